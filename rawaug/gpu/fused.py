"""The whole noise chain in one Triton kernel: each element of clean is read once and its
noisy value written once; the stages are the CPU kernel's (``rawaug.cpu.fused``), in the
same order, from the same counter streams. Draws after the shot noise evaluate their
quantiles in float32 registers; the fixed patterns that feed the Poisson draw (PRNU, DSNU)
use the CPU's normal table, so that both backends count the same electrons. ``FLAGS`` and ``FLAGS_HIGH``
(stage-flag words 0 and 1) are compile-time constants, so the
stages a model does not use are not in its kernel."""
from __future__ import annotations

import triton
import triton.language as tl

from ..engine import layout as L
from .counter import draw, normal_upper, symmetric_table, tail_of, tukey_upper, unit
from .poisson import poisson_count


def _column(name: str) -> tl.constexpr:
    """A column of the (B, P) parameter tensor, as a constant the Triton compiler accepts
    (compiled kernels read module globals only as constexpr; the interpreter reads any)."""
    return tl.constexpr(L.COLUMN[name])


C_K, C_RATIO, C_PRNU = _column("k"), _column("ratio"), _column("prnu_sigma")
C_DARK_E, C_DSNU_LOG, C_DARK_C0 = _column("dark_e"), _column("dsnu_log"), _column("dark_c0")
C_DSNU_COL = _column("dsnu_col_log")
C_DSNU_ROW = _column("dsnu_row_log")
C_LF, C_LF_GH, C_LF_GW = _column("lowfreq_sigma"), _column("lowfreq_gh"), _column("lowfreq_gw")
C_CM_REC0 = _column("codemap_record_c0")  # channel c's record: C_CM_REC0 + c
C_RQ_REC, C_RQ_SCALE = _column("readq_record"), _column("readq_scale")
C_LRD, C_LCD, C_LM, C_LLS, C_LNEG = (_column("lines_row_density"), _column("lines_col_density"), _column("lines_median"),
                                     _column("lines_log_std"), _column("lines_negative"))
Z_MAX = tl.constexpr(L.READ_TABLE_Z)
C_TL, C_LAM, C_G, C_R = _column("sigma_tl"), _column("lambda"), _column("sigma_g"), _column("sigma_r")
C_CS, C_CF, C_FS, C_FR = _column("col_sigma"), _column("col_fixed"), _column("fpn_sigma"), _column("fpn_record")
C_CRHO = _column("col_rho")
C_FOY, C_FOX, C_FH, C_FW = _column("fpn_oy"), _column("fpn_ox"), _column("fpn_h"), _column("fpn_w")
C_FGH, C_FGW = _column("fpn_gh"), _column("fpn_gw")
C_GLS, C_GLR, C_GLOY, C_GLOX = _column("glow_s"), _column("glow_record"), _column("glow_oy"), _column("glow_ox")
C_GLH, C_GLW, C_GLGH, C_GLGW = _column("glow_h"), _column("glow_w"), _column("glow_gh"), _column("glow_gw")
C_NL, C_TRAP = _column("nl_c0"), _column("trap_dn")
C_XT0 = _column("xt_0")
C_BF0, C_BA0 = _column("band_f0"), _column("band_a0")
C_CBF0, C_CBA0 = _column("cband_f0"), _column("cband_a0")
C_DHD, C_DHE, C_DHL = _column("dhot_density"), _column("dhot_e"), _column("dhot_log_std")
C_CGS, C_CGT = _column("colgain_sigma"), _column("colgain_frame")
C_RGF, C_RGT = _column("rowgain_fixed"), _column("rowgain_frame")
C_GGR, C_GGPY, C_GGPX, C_GGOY, C_GGOX = (_column(n) for n in ("ggrid_record", "ggrid_py", "ggrid_px", "ggrid_oy", "ggrid_ox"))
C_GGCONV = _column("ggrid_conv")
C_DCD, C_DCE, C_DCL = _column("dcol_density"), _column("dcol_e"), _column("dcol_log_std")
C_DRD, C_DRE, C_DRL = _column("drow_density"), _column("drow_e"), _column("drow_log_std")
C_NZD, C_NZM, C_NZL = _column("noisy_density"), _column("noisy_median"), _column("noisy_log_std")
C_TDD, C_TDE, C_TDL, C_TDH = _column("drts_density"), _column("drts_e"), _column("drts_log_std"), _column("drts_high")
C_NCD, C_NCM, C_NCL = _column("ncol_density"), _column("ncol_median"), _column("ncol_log_std")
C_RRD, C_RRM, C_RRL, C_RRH = _column("rrts_density"), _column("rrts_median"), _column("rrts_log_std"), _column("rrts_high")
C_TPS, C_TPC0, C_TPR0 = _column("tap_sigma"), _column("tap_c0"), _column("tap_r0")
C_TPOY, C_TPOX, C_TPH, C_TPW = _column("tap_oy"), _column("tap_ox"), _column("tap_h"), _column("tap_w")
C_TGR, C_TGC0, C_TGR0 = _column("tgain_record"), _column("tgain_c0"), _column("tgain_r0")
C_TGOY, C_TGOX, C_TGH, C_TGW = _column("tgain_oy"), _column("tgain_ox"), _column("tgain_h"), _column("tgain_w")
C_LGRD, C_LGCD, C_LGM, C_LGLS, C_LGNEG = (_column("lgain_row_density"), _column("lgain_col_density"), _column("lgain_median"),
                                        _column("lgain_log_std"), _column("lgain_negative"))
C_DDF = _column("dark_factor")
C_DNS = _column("dark_noise")
C_GNS = _column("gain_noise")
C_RH = _column("row_h")
C_FF, C_FF_GH, C_FF_GW = _column("ffield_sigma"), _column("ffield_gh"), _column("ffield_gw")
C_PGD, C_PGM, C_PGL, C_PGN = (_column(n) for n in ("pgain_density", "pgain_median", "pgain_log_std", "pgain_negative"))
C_DNL_P, C_DNL_E0 = _column("dnl_period"), _column("dnl_e0")
TPE = tl.constexpr(L.TAP_EDGES)
C_DOFF = _column("dark_offset")
C_DRIFT = _column("black_drift")
C_RG = _column("read_gain")
C_FG = _column("frame_gain")
C_LMR, C_LMOY, C_LMOX, C_LMLH, C_LMLW = (_column(n) for n in ("lmap_record", "lmap_oy", "lmap_ox", "lmap_lh", "lmap_lw"))
C_SPD, C_SPM, C_SPL, C_SPN = _column("spike_density"), _column("spike_median"), _column("spike_log_std"), _column("spike_negative")
C_CRD, C_CRM, C_CRL, C_CRH = _column("crts_density"), _column("crts_median"), _column("crts_log_std"), _column("crts_high")
C_DBX0, C_DBY0, C_DBA0, C_DBF0 = _column("dband_fx0"), _column("dband_fy0"), _column("dband_a0"), _column("dband_f0")
C_RF, C_RC = _column("rowfix_sigma"), _column("rowch_sigma")
TONES = tl.constexpr(L.BAND_TONES)
FIXED_PHASE = tl.constexpr(L.FIXED_PHASE)
C_RMC0, C_RMY0, C_RMX0 = _column("rmap_c0"), _column("rmap_y0"), _column("rmap_x0")
C_RMOY, C_RMOX, C_RMH, C_RMW = _column("rmap_oy"), _column("rmap_ox"), _column("rmap_h"), _column("rmap_w")
C_RMYE0, C_RMXE0, C_RMCR = _column("rmap_ye0"), _column("rmap_xe0"), _column("rmap_cell_record")
NB = tl.constexpr(L.READ_MAP_BLOCKS)
C_SH = _column("shared_sigma")
C_RTD, C_RTM, C_RTL, C_RTH = _column("rts_density"), _column("rts_median"), _column("rts_log_std"), _column("rts_high")
C_DD, C_DL0 = _column("dead_density"), _column("dead_l0")
C_DCOL, C_DROW, C_DPART, C_DEND = _column("dead_col_density"), _column("dead_row_density"), _column("dead_partial"), _column("dead_to_end")
C_DCLO, C_DCHI = _column("dead_cut_lo"), _column("dead_cut_hi")
C_SBZ0, C_SBLO, C_SBHI = _column("stuck_z0"), _column("stuck_low"), _column("stuck_high")
C_BKCP, C_BKRP, C_BKC0, C_BKR0 = _column("bank_cp"), _column("bank_rp"), _column("bank_c0"), _column("bank_r0")
NDL = tl.constexpr(L.DEAD_LEVELS)
C_DR0, C_CDR0 = _column("drift_a0"), _column("cdrift_a0")
C_RPD, CHAIN = _column("repeat_density"), tl.constexpr(L.REPEAT_CHAIN)
C_BNCP, C_BNC0 = _column("bnoise_cp"), _column("bnoise_c0")
C_CLD, C_CLE, C_CLL, C_CLS = _column("dclus_density"), _column("dclus_e"), _column("dclus_log_std"), _column("dclus_size")
CLUSTER_MAX = tl.constexpr(L.CLUSTER_MAX)
C_BRD, C_BRS = _column("burst_density"), _column("burst_sigma")
C_CBD, C_CBS = _column("cburst_density"), _column("cburst_sigma")
C_WELL, C_WELLS = _column("well_e"), _column("well_spread")
C_RPAIR, C_DRN = _column("rpair_sigma"), _column("dark_row_sigma")
C_RAMP_ROW, C_RAMP_COL = _column("ramp_row"), _column("ramp_col")
C_BSTEP_AT, C_BSTEP_DN = _column("bstep_at"), _column("bstep_dn")
C_MASK_T, C_MASK_B, C_MASK_L, C_MASK_R = (_column(n) for n in ("mask_top", "mask_bottom", "mask_left", "mask_right"))
C_RTS, C_RTC0, C_RTOX, C_RTW = _column("rtap_sigma"), _column("rtap_c0"), _column("rtap_ox"), _column("rtap_w")
C_CTS0, C_CTC0, C_CTOX, C_CTW = _column("ctap_s0"), _column("ctap_c0"), _column("ctap_ox"), _column("ctap_w")
C_CGRS, C_CGRW, C_CGR0 = _column("cgroup_sigma"), _column("cgroup_width"), _column("cgroup_start")
C_RSD, C_RSM, C_RSL, C_RSN = _column("rspike_density"), _column("rspike_median"), _column("rspike_log_std"), _column("rspike_negative")
C_RWY0, C_RWOY, C_RWH = _column("rowmap_y0"), _column("rowmap_oy"), _column("rowmap_h")
C_HTD = _column("hot_tile_density")
OCT = tl.constexpr(L.DRIFT_OCTAVES)
XT_PAD = tl.constexpr(L.XTALK_PAD)
XT_DY0, XT_DX0, XT_DY1, XT_DX1, XT_DY2, XT_DX2, XT_DY3, XT_DX3, XT_DY4, XT_DX4, XT_DY5, XT_DX5, XT_DY6, XT_DX6 = (
    tl.constexpr(d) for tap in L.XTALK_TAPS for d in tap)
C_SENSOR = _column("sensor")
C_SHC, C_SHX, C_SHY = _column("share_c"), _column("share_x"), _column("share_y")
C_SHD1, C_SHD2 = _column("share_d1"), _column("share_d2")
C_FMR, C_FMOY, C_FMOX, C_FMH, C_FMW = _column("fmap_record"), _column("fmap_oy"), _column("fmap_ox"), _column("fmap_h"), _column("fmap_w")
C_FMGH, C_FMGW = _column("fmap_gh"), _column("fmap_gw")
C_HD, C_HM, C_HL = _column("hot_density"), _column("hot_median"), _column("hot_log_std")
C_Q, C_B0, C_BS, C_BC, C_CL = (_column("step_dn"), _column("bias_r"), _column("ble_sigma"),
                               _column("ble_channel_sigma"), _column("clip_floor"))
S = {name: tl.constexpr(slot) for name, slot in L.STREAM.items()}  # stream slots, constexpr as above
K_SHOT, K_SHOT_REST, K_SHOT_COARSE, K_READ = S["shot"], S["shot_rest"], S["shot_coarse"], S["read"]
K_ROW, K_COL, K_QUANT, K_BLE = S["row"], S["col"], S["quant"], S["ble"]
K_DSNU, K_LOWFREQ = S["dsnu_pattern"], S["lowfreq"]
K_LINES_ROW, K_LINES_COL = S["lines_row"], S["lines_col"]
K_LINES_ROW_CUT, K_LINES_COL_CUT = S["lines_row_cut"], S["lines_col_cut"]
C_LPART, C_LEND, C_LCLO, C_LCHI = _column("lines_partial"), _column("lines_to_end"), _column("lines_cut_lo"), _column("lines_cut_hi")
K_LGAIN_ROW, K_LGAIN_COL = S["lgain_row"], S["lgain_col"]
K_XTALK, K_BAND, K_ROW_PATTERN, K_ROW_CHANNEL = S["xtalk"], S["band"], S["row_pattern"], S["row_channel"]
K_READ_MAP, K_SHARED = S["read_map"], S["shared"]
K_RTS_WHERE, K_RTS_SIZE, K_RTS_STATE = S["rts_where"], S["rts_size"], S["rts_state"]
K_DEAD_WHERE, K_DEAD_LEVEL = S["dead_where"], S["dead_level"]
K_DEAD_COL, K_DEAD_ROW = S["dead_col"], S["dead_row"]
K_ROW_DRIFT, K_ROW_DRIFT_PHASE = S["row_drift"], S["row_drift_phase"]
K_COL_DRIFT, K_COL_DRIFT_PHASE = S["col_drift"], S["col_drift_phase"]
K_ROW_REPEAT, K_BANK_NOISE = S["row_repeat"], S["bank_noise"]
K_DCLUS_WHERE, K_DCLUS_SIZE = S["dclus_where"], S["dclus_size"]
K_BURST_ROW, K_BURST_NOISE = S["burst_row"], S["burst_noise"]
K_BURST_COL, K_BURST_COL_NOISE = S["burst_col"], S["burst_col_noise"]
K_WELL_PATTERN, K_COL_GROUP, K_BLACK_RAMP, K_ROW_PAIR = S["well_pattern"], S["col_group"], S["black_ramp"], S["row_pair"]
K_DARK_ROW_NOISE, K_ROW_TAP = S["dark_row_noise"], S["row_tap"]
K_COL_TAP = S["col_tap"]
K_RSPIKE_WHERE, K_RSPIKE_SIZE = S["rspike_where"], S["rspike_size"]
K_ROW_MAP = S["row_map"]
K_HOT_TILE_WHERE, K_HOT_TILE_SIZE = S["hot_tile_where"], S["hot_tile_size"]
K_COL_BAND = S["col_band"]
K_DHOT_WHERE, K_DHOT_SIZE = S["dhot_where"], S["dhot_size"]
K_COLGAIN, K_COLGAIN_FRAME = S["colgain_pattern"], S["colgain_frame"]
K_DSNU_COL = S["dsnu_col_pattern"]
K_DSNU_ROW = S["dsnu_row_pattern"]
K_ROWGAIN, K_ROWGAIN_FRAME = S["rowgain_pattern"], S["rowgain_frame"]
K_DCOL_WHERE, K_DCOL_SIZE = S["dcol_where"], S["dcol_size"]
K_DROW_WHERE, K_DROW_SIZE = S["drow_where"], S["drow_size"]
K_DRTS_WHERE, K_DRTS_SIZE, K_DRTS_STATE = S["drts_where"], S["drts_size"], S["drts_state"]
K_NCOL_WHERE, K_NCOL_SIZE, K_NCOL_READ = S["ncol_where"], S["ncol_size"], S["ncol_read"]
K_RRTS_WHERE, K_RRTS_SIZE, K_RRTS_STATE = S["rrts_where"], S["rrts_size"], S["rrts_state"]
K_TAP = S["tap"]
K_NOISY_WHERE, K_NOISY_SIZE, K_NOISY_READ = S["noisy_where"], S["noisy_size"], S["noisy_read"]
K_SPIKE_WHERE, K_SPIKE_SIZE = S["spike_where"], S["spike_size"]
K_CRTS_WHERE, K_CRTS_SIZE, K_CRTS_STATE = S["crts_where"], S["crts_size"], S["crts_state"]
K_DIAG_BAND = S["diag_band"]
K_DARK_NOISE = S["dark_noise"]
K_GAIN_NOISE = S["gain_noise"]
K_PGAIN = S["pgain"]
K_FFIELD = S["ffield"]
K_PRNU, K_FPN, K_HOT_WHERE, K_HOT_SIZE, K_COL_PATTERN = (S["prnu_pattern"], S["fpn_pattern"], S["hot_where"],
                                                         S["hot_size"], S["col_pattern"])


@triton.jit
def _normal(z):
    t, sign = tail_of(z)
    return (sign * normal_upper(t)).to(tl.float64)


@triton.jit
def _grid_power(g, e):
    # g ** e of a gain g >= 0, as exp(e log g): g where e is 1, 1 where e is 0, 0 for g 0 and e > 0
    p = tl.where(g > 0.0, tl.exp(e * tl.log(tl.maximum(g, 1e-300))), 0.0)
    return tl.where(e == 1.0, g, tl.where(e == 0.0, 1.0, p))


@triton.jit
def _bilinear(y, x, H, W, gh, gw):
    """(y0, x0, y1, x1, fy, fx) of bilinear upsampling, as ``rawaug.cpu.fused._bilinear_at``."""
    ghf = gh.to(tl.float64)
    gwf = gw.to(tl.float64)
    sy = tl.minimum(tl.maximum((y.to(tl.float64) + 0.5) * ghf / H - 0.5, 0.0), ghf - 1.0)
    sx = tl.minimum(tl.maximum((x.to(tl.float64) + 0.5) * gwf / W - 0.5, 0.0), gwf - 1.0)
    y0 = sy.to(tl.int64)
    x0 = sx.to(tl.int64)
    return y0, x0, tl.minimum(y0 + 1, gh - 1), tl.minimum(x0 + 1, gw - 1), sy - y0.to(tl.float64), sx - x0.to(tl.float64)


@triton.jit
def _normal_grid(normal_ptr, key, base, y, x, H, W, gh, gw):
    """A standard-normal grid (gh x gw, counter (base + i) * gw + j) upsampled bilinearly at
    (y, x), as ``rawaug.cpu.fused.lowfreq_at`` (``base``: the frame's or the sensor's rows)."""
    y0, x0, y1, x1, fy, fx = _bilinear(y, x, H, W, gh, gw)
    z00 = symmetric_table(normal_ptr, draw(key, ((base + y0) * gw + x0).to(tl.uint64)))
    z01 = symmetric_table(normal_ptr, draw(key, ((base + y0) * gw + x1).to(tl.uint64)))
    z10 = symmetric_table(normal_ptr, draw(key, ((base + y1) * gw + x0).to(tl.uint64)))
    z11 = symmetric_table(normal_ptr, draw(key, ((base + y1) * gw + x1).to(tl.uint64)))
    return (z00 * (1.0 - fx) + z01 * fx) * (1.0 - fy) + (z10 * (1.0 - fx) + z11 * fx) * fy


@triton.jit
def _defect_line(normal_ptr, key, line, density, median, log_std, negative):
    """As ``rawaug.cpu.fused.defect_line_at``: the offset of sensor lines ``line`` (uint64)."""
    size = median * tl.exp(log_std * symmetric_table(normal_ptr, draw(key, 3 * line + 1)))
    size = tl.where(unit(draw(key, 3 * line + 2)) < negative, -size, size)
    return tl.where(unit(draw(key, 3 * line)) < density, size, 0.0)


@triton.jit
def _line_part(key, line, partial, to_end, cut_lo, cut_hi, pos, n):
    """As ``rawaug.cpu.fused.line_part``: 1.0 where sensor position ``pos`` of the ``n`` along
    sensor lines ``line`` (uint64) lies in the line's defect, else 0.0."""
    along = pos.to(tl.float64) + 0.5
    cut = (cut_lo + (cut_hi - cut_lo) * unit(draw(key, 3 * line + 2))) * n
    inside = tl.where(unit(draw(key, 3 * line + 1)) < to_end, along >= cut, along < cut)
    whole = unit(draw(key, 3 * line)) >= partial  # always where partial is 0
    return tl.where(whole, 1.0, tl.where(inside, 1.0, 0.0))


@triton.jit
def _dead_line_slot(key, line, density, partial, to_end, cut_lo, cut_hi, pos, n):
    """As ``rawaug.cpu.fused.dead_line_slot``: the level slot where sensor lines ``line`` (uint64) are dead at ``pos``, else -1."""
    along = pos.to(tl.float64) + 0.5
    cut = (cut_lo + (cut_hi - cut_lo) * unit(draw(key, 5 * line + 3))) * n
    ends = unit(draw(key, 5 * line + 2)) < to_end
    outside = (unit(draw(key, 5 * line + 1)) < partial) & tl.where(ends, along < cut, along >= cut)
    slot = tl.minimum((unit(draw(key, 5 * line + 4)) * NDL).to(tl.int64), NDL - 1)
    return tl.where((unit(draw(key, 5 * line)) < density) & ~outside, slot, -1)


@triton.jit
def _shading(grids_ptr, GH, GW, record, y, x, h, w, gh, gw, live):
    """Bilinear upsampling of the gh x gw grid ``record`` of a table of GH x GW (padded) records at (y, x)."""
    y0, x0, y1, x1, fy, fx = _bilinear(y, x, h, w, gh, gw)
    base = grids_ptr + record * GH * GW
    top = tl.load(base + y0 * GW + x0, mask=live, other=0.0) * (1.0 - fx) + tl.load(base + y0 * GW + x1, mask=live, other=0.0) * fx
    bottom = tl.load(base + y1 * GW + x0, mask=live, other=0.0) * (1.0 - fx) + tl.load(base + y1 * GW + x1, mask=live, other=0.0) * fx
    return top * (1.0 - fy) + bottom * fy


@triton.jit
def _tone(key, v, j: tl.constexpr, b, line, F0: tl.constexpr, A0: tl.constexpr):
    """As one tone of ``rawaug.cpu.fused.banding_at``: a_j cos(2 pi f_j line + phi_j), f_j and
    a_j in columns F0 + j and A0 + j."""
    phase = 6.283185307179586 * unit(draw(key, (b.to(tl.int64) * TONES + j).to(tl.uint64) + tl.zeros_like(line).to(tl.uint64)))
    arg = 6.283185307179586 * _col(v, F0 + j) * line.to(tl.float64) + phase.to(tl.float64)
    return _col(v, A0 + j) * tl.cos(arg)


@triton.jit
def _diag_tone(key, v, j: tl.constexpr, b, sensor, ry, rx):
    """As one tone of ``rawaug.cpu.fused.diagonal_banding_at``: a_j cos(2 pi (fx_j rx + fy_j ry) + phi_j)
    + f_j cos(2 pi (fx_j rx + fy_j ry) + psi_j), psi_j the sensor's."""
    zero = tl.zeros_like(rx).to(tl.uint64)
    phase = 6.283185307179586 * unit(draw(key, (b.to(tl.int64) * TONES + j).to(tl.uint64) + zero))
    fixed = 6.283185307179586 * unit(draw(key, (sensor * TONES + j + FIXED_PHASE).to(tl.uint64) + zero))
    arg = 6.283185307179586 * (_col(v, C_DBX0 + j) * rx.to(tl.float64) + _col(v, C_DBY0 + j) * ry.to(tl.float64))
    return _col(v, C_DBA0 + j) * tl.cos(arg + phase.to(tl.float64)) + _col(v, C_DBF0 + j) * tl.cos(arg + fixed.to(tl.float64))


@triton.jit
def _drift_octave(key, key_phase, normal_ptr, v, a0: tl.constexpr, first: tl.constexpr, j: tl.constexpr, b, ry):
    """As one octave of ``rawaug.cpu.fused.drift_at`` (amplitudes from column ``a0``, nodes every 2^(j + first) lines)."""
    s: tl.constexpr = 1 << (j + first)
    bj = b.to(tl.int64) * OCT + j
    t = ry.to(tl.int64) + (unit(draw(key_phase, bj.to(tl.uint64) + tl.zeros_like(ry).to(tl.uint64))) * s).to(tl.int64)
    i = t // s
    f = (t - i * s).to(tl.float64) / s
    base = (bj << 24) + i
    z0 = _normal(draw(key, base.to(tl.uint64)))
    z1 = _normal(draw(key, (base + 1).to(tl.uint64)))
    return _col(v, a0 + j) * (z0 * (1.0 - f) + z1 * f)


@triton.jit
def _xtalk_tap(key, v, i: tl.constexpr, dy: tl.constexpr, dx: tl.constexpr, b, ry, rx, RH, RW):
    """As one tap of ``rawaug.cpu.fused.crosstalk_at``: h g(ry - dy, rx - dx)."""
    base = b.to(tl.int64) * (RH + 2 * XT_PAD)
    there = ((base + ry - dy + XT_PAD) * (RW + 2 * XT_PAD) + rx - dx + XT_PAD).to(tl.uint64)
    return _col(v, C_XT0 + i) * _normal(draw(key, there))


@triton.jit
def _shot_deviation(s, g, k, key_fine, key_rest, key_coarse,
                    f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                    c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, active, POISSON: tl.constexpr):
    """(mean, shot deviation) in DN at signal ``s``, as ``rawaug.cpu.fused``'s shot stage: the
    exact Poisson count less max(s, 0), or the Gaussian approximation's ``sqrt(K max(s, 0)) z``."""
    if POISSON:
        mean = tl.maximum(s, 0.0)
        count = poisson_count(s / k, key_fine, key_rest, key_coarse, g, f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size,
                              f_kmin, c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, active)
        return mean, k * count - mean
    else:
        return s, tl.sqrt(k * tl.maximum(s, 0.0)) * _normal(draw(key_fine, g))


@triton.jit
def _neighbour_deviation(clean_ptr, b, ry, rx, dy: tl.constexpr, dx: tl.constexpr, H, W, scale_in, gain, dark, k, weight,
                         key_fine, key_rest, key_coarse,
                         f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                         c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live, POISSON: tl.constexpr):
    """``weight`` x the shot deviation of raw pixel (ry + dy, rx + dx), from its clean value
    through this pixel's ``gain`` and ``dark`` signal, 0 outside the frame (as
    ``rawaug.cpu.fused.neighbour_at`` and the CPU's shot stage)."""
    ny = ry + dy
    nx = rx + dx
    inside = live & (ny >= 0) & (ny < 2 * H) & (nx >= 0) & (nx < 2 * W) & ((dark * 0.0 + weight) != 0.0)  # weight: a scalar, broadcast
    cn = tl.where((ny & 1) == 0, tl.where((nx & 1) == 0, 0, 1), tl.where((nx & 1) == 0, 3, 2))
    gn = ((b.to(tl.int64) * 4 + cn) * H + (ny >> 1)) * W + (nx >> 1)
    sn = tl.load(clean_ptr + gn, mask=inside, other=0.0).to(tl.float64) * scale_in * gain + dark
    ok = inside & (sn == sn) & (tl.abs(sn) < float("inf"))
    sn = tl.where(ok, sn, 0.0)
    _, dev = _shot_deviation(sn, gn.to(tl.uint64), k, key_fine, key_rest, key_coarse,
                             f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                             c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, ok, POISSON)
    return tl.where(ok, weight * dev, 0.0)


@triton.jit
def _key(keys_ptr, slot: tl.constexpr):
    return tl.load(keys_ptr + slot).to(tl.uint64, bitcast=True)


@triton.jit
def _col(v_ptr, col: tl.constexpr):
    return tl.load(v_ptr + col)


@triton.jit
def _block(v, first: tl.constexpr, pos, size):
    """As ``rawaug.cpu.fused.block_at``: the read-noise map block of packed position ``pos`` of a
    frame of ``size``, from the edges at ``v[first:first + NB - 1]`` (fractions of ``size``)."""
    block = tl.zeros_like(pos).to(tl.int64)
    for i in tl.static_range(NB - 1):
        block += (pos >= tl.load(v + first + i) * size).to(tl.int64)
    return block


@triton.jit
def _tap(v, first: tl.constexpr, offset: tl.constexpr, size: tl.constexpr, pos, line_set, full):
    """As ``rawaug.cpu.fused.tap_at``: the readout tap along one axis of packed position ``pos``
    (sensor line 2 (pos + the window's offset column) + ``line_set``), from the edges at
    ``v[first:first + TAP_EDGES]`` (fractions of the frame's sensor lines: twice the window's
    frame size column, or twice ``full`` where it is 0)."""
    n = _col(v, size)
    lines = 2.0 * tl.where(n > 0.0, n, full.to(tl.float64))
    line = (2 * (pos + _col(v, offset).to(tl.int64)) + line_set).to(tl.float64)
    tap = tl.zeros_like(line).to(tl.int64)
    for i in tl.static_range(TPE):
        tap += (line >= tl.load(v + first + i) * lines).to(tl.int64)
    return tap


@triton.jit
def fused_kernel(clean_ptr, out_ptr, values_ptr, keys_ptr, span, H, W,
                 f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                 c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin,
                 grids_ptr, GH, GW, normal_ptr, code_ptr, CODE_N, read_ptr, READ_N,
                 FLAGS: tl.constexpr, FLAGS_HIGH: tl.constexpr, P: tl.constexpr, BLOCK: tl.constexpr):
    plane = tl.program_id(1)  # b * 4 + c
    b = plane // 4
    c = plane % 4
    idx = tl.program_id(0).to(tl.int64) * BLOCK + tl.arange(0, BLOCK)
    hw = H.to(tl.int64) * W
    live = idx < hw
    y = idx // W
    x = idx % W
    row_set = c // 2
    col_set = tl.where((c == 0) | (c == 3), 0, 1)
    v = values_ptr + b.to(tl.int64) * P
    if FLAGS_HIGH & 2:  # (word 1) repeated rows: as rawaug.cpu.fused.repeated_row_source, the whole chain of the row repeated
        kr = _key(keys_ptr, K_ROW_REPEAT)
        density = _col(v, C_RPD)
        going = live
        for _ in tl.static_range(CHAIN):
            repeat = going & (y >= 1) & (unit(draw(kr, ((b.to(tl.int64) * 2 * H + 2 * y + row_set)).to(tl.uint64))) < density)
            y = tl.where(repeat, y - 1, y)
            going = repeat
    src = y * W + x  # the element whose chain this one runs (itself, or its column in the row it repeats)
    g = (plane.to(tl.int64) * hw + src).to(tl.uint64)
    sensor = _col(v, C_SENSOR).to(tl.int64)  # fixed patterns of this sample's sensor instance: planes of their own
    p = ((sensor * 4 + c) * hw + src).to(tl.uint64)
    k = _col(v, C_K)
    ratio = _col(v, C_RATIO)
    scale_in = span / ratio
    s = tl.load(clean_ptr + plane.to(tl.int64) * hw + src, mask=live, other=0.0).to(tl.float64) * scale_in
    s_photo = s  # the photo signal before the pixel's gains (charge sharing takes its neighbours' through them)
    if FLAGS & 1:  # PRNU
        s *= 1.0 + _col(v, C_PRNU) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_PRNU), p))
    grid_gain = 1.0  # measured gain grid: the periodic gain at this pixel
    if FLAGS & 4398046511104:  # ... its optical share before the Poisson draw
        gg = grids_ptr + (_col(v, C_GGR).to(tl.int64) + c) * GH.to(tl.int64) * GW.to(tl.int64)
        gy = (y + _col(v, C_GGOY).to(tl.int64)) % _col(v, C_GGPY).to(tl.int64)
        gx = (x + _col(v, C_GGOX).to(tl.int64)) % _col(v, C_GGPX).to(tl.int64)
        grid_gain = tl.load(gg + gy * GW.to(tl.int64) + gx, mask=live, other=1.0)
        s *= _grid_power(grid_gain, 1.0 - _col(v, C_GGCONV))
    if FLAGS_HIGH & 32768:  # (word 1) masked lines: no light at the frame's edges (the dark signal stays)
        sy = (2 * y + row_set).to(tl.float64)
        sx = (2 * x + col_set).to(tl.float64)
        dark = ((sy < _col(v, C_MASK_T)) | (sy >= 2 * H - _col(v, C_MASK_B)) | (sx < _col(v, C_MASK_L))
                | (sx >= 2 * W - _col(v, C_MASK_R)))
        s = tl.where(dark, 0.0 * s, s)
    s_pixel = s  # ... and after them: the dark signal is what the stages below add
    if FLAGS & 16384:  # dark current: K * dark electrons * a log-normal DSNU map of mean 1, before shot noise
        sl = _col(v, C_DSNU_LOG)
        sc = _col(v, C_DSNU_COL)  # the sensor column's log-normal factor of mean 1 (column DSNU)
        col = tl.where(sc > 0.0, sc * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_DSNU_COL), ((sensor * 2 + col_set) * W + x).to(tl.uint64))) - 0.5 * sc * sc, 0.0)
        sr = _col(v, C_DSNU_ROW)  # the sensor row's log-normal factor of mean 1 (row DSNU)
        col += tl.where(sr > 0.0, sr * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_DSNU_ROW), ((sensor * 2 + row_set) * H + y).to(tl.uint64))) - 0.5 * sr * sr, 0.0)
        s += k * _col(v, C_DARK_E) * tl.load(v + C_DARK_C0 + c) * tl.exp(sl * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_DSNU), p)) - 0.5 * sl * sl + col)
    if FLAGS & 524288:  # amplifier glow: K * exposure * a smooth dark-current map (e-/s), a window of glow_h x glow_w
        gh_ = _col(v, C_GLH)
        gw_ = _col(v, C_GLW)
        gh_ = tl.where(gh_ > 0.0, gh_, H.to(tl.float64))
        gw_ = tl.where(gw_ > 0.0, gw_, W.to(tl.float64))
        s += k * _col(v, C_GLS) * _shading(grids_ptr, GH.to(tl.int64), GW.to(tl.int64), _col(v, C_GLR).to(tl.int64),
                                          y.to(tl.float64) + _col(v, C_GLOY), x.to(tl.float64) + _col(v, C_GLOX), gh_, gw_,
                                          _col(v, C_GLGH).to(tl.int64), _col(v, C_GLGW).to(tl.int64), live)
    if FLAGS & 2147483648:  # hot pixels of dark current: their electrons, before shot noise (the CPU's normal table)
        dhot = unit(draw(_key(keys_ptr, K_DHOT_WHERE), p)) < _col(v, C_DHD)
        dark = k * _col(v, C_DHE) * tl.exp(_col(v, C_DHL) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_DHOT_SIZE), p)))
        s += tl.where(dhot, dark, 0.0)
    if FLAGS_HIGH & 8:  # (word 1) hot clusters: the electrons of every patch seeded up to size - 1 sensor pixels above and left
        csize = _col(v, C_CLS).to(tl.int64)
        cdensity = _col(v, C_CLD)
        celectrons = k * _col(v, C_CLE)
        clog = _col(v, C_CLL)
        kw, ks = _key(keys_ptr, K_DCLUS_WHERE), _key(keys_ptr, K_DCLUS_SIZE)
        for dy in tl.static_range(CLUSTER_MAX):
            yy = 2 * y + row_set - dy
            for dx in tl.static_range(CLUSTER_MAX):
                xx = 2 * x + col_set - dx
                q = ((sensor * 2 * H + tl.maximum(yy, 0)) * 2 * W + tl.maximum(xx, 0)).to(tl.uint64)
                seeded = (dy < csize) & (dx < csize) & (yy >= 0) & (xx >= 0) & (unit(draw(kw, q)) < cdensity)
                s += tl.where(seeded, celectrons * tl.exp(clog * symmetric_table(normal_ptr, draw(ks, q))), 0.0)
    if FLAGS & 140737488355328:  # dark-current telegraph: a pixel's step of electrons in the frames where it is high, before shot noise
        high = (unit(draw(_key(keys_ptr, K_DRTS_WHERE), p)) < _col(v, C_TDD)) & (unit(draw(_key(keys_ptr, K_DRTS_STATE), g)) < _col(v, C_TDH))
        step = k * _col(v, C_TDE) * tl.exp(_col(v, C_TDL) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_DRTS_SIZE), p)))
        s += tl.where(high, step, 0.0)
    if FLAGS & 17179869184:  # leaky columns: a sensor column's dark electrons, before shot noise (keyed by the column)
        q = ((sensor * 2 + col_set) * W + x).to(tl.uint64)
        leaky = unit(draw(_key(keys_ptr, K_DCOL_WHERE), q)) < _col(v, C_DCD)
        dark = k * _col(v, C_DCE) * tl.exp(_col(v, C_DCL) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_DCOL_SIZE), q)))
        s += tl.where(leaky, dark, 0.0)
    if FLAGS & 35184372088832:  # leaky rows: a sensor row's dark electrons, before shot noise (keyed by the row)
        q = ((sensor * 2 + row_set) * H + y).to(tl.uint64)
        leaky = unit(draw(_key(keys_ptr, K_DROW_WHERE), q)) < _col(v, C_DRD)
        dark = k * _col(v, C_DRE) * tl.exp(_col(v, C_DRL) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_DROW_SIZE), q)))
        s += tl.where(leaky, dark, 0.0)
    if FLAGS & 9007199254740992:  # dark-signal drift: this frame's factor on every dark signal above
        s = s_pixel + _col(v, C_DDF) * (s - s_pixel)
    if FLAGS & 17592186044416:  # charge sharing: the shot deviations of this pixel and its raw neighbours, mixed
        if FLAGS & 6:
            finite = (s == s) & (tl.abs(s) < float("inf"))  # NaN/Inf pass through
            kf, kr, kc = _key(keys_ptr, K_SHOT), _key(keys_ptr, K_SHOT_REST), _key(keys_ptr, K_SHOT_COARSE)
            sf = tl.where(finite, s, 0.0)
            mean, dev = _shot_deviation(sf, g, k, kf, kr, kc, f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                                        c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live & finite,
                                        (FLAGS & 2) != 0)
            gain = tl.where(s_photo != 0.0, s_pixel / tl.where(s_photo != 0.0, s_photo, 1.0), 1.0)
            dark = s - s_pixel
            ry = 2 * y + row_set
            rx = 2 * x + col_set
            wx = _col(v, C_SHX)
            wy = _col(v, C_SHY)
            shared = _col(v, C_SHC) * dev
            shared += _neighbour_deviation(clean_ptr, b, ry, rx, 0, -1, H, W, scale_in, gain, dark, k, wx, kf, kr, kc,
                                           f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                                           c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live & finite, (FLAGS & 2) != 0)
            shared += _neighbour_deviation(clean_ptr, b, ry, rx, 0, 1, H, W, scale_in, gain, dark, k, wx, kf, kr, kc,
                                           f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                                           c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live & finite, (FLAGS & 2) != 0)
            shared += _neighbour_deviation(clean_ptr, b, ry, rx, -1, 0, H, W, scale_in, gain, dark, k, wy, kf, kr, kc,
                                           f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                                           c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live & finite, (FLAGS & 2) != 0)
            shared += _neighbour_deviation(clean_ptr, b, ry, rx, 1, 0, H, W, scale_in, gain, dark, k, wy, kf, kr, kc,
                                           f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                                           c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live & finite, (FLAGS & 2) != 0)
            if FLAGS_HIGH & 131072:  # (word 1) ... and the diagonal neighbours'
                wd1 = _col(v, C_SHD1)
                wd2 = _col(v, C_SHD2)
                shared += _neighbour_deviation(clean_ptr, b, ry, rx, -1, -1, H, W, scale_in, gain, dark, k, wd1, kf, kr, kc,
                                               f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                                               c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live & finite, (FLAGS & 2) != 0)
                shared += _neighbour_deviation(clean_ptr, b, ry, rx, 1, 1, H, W, scale_in, gain, dark, k, wd1, kf, kr, kc,
                                               f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                                               c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live & finite, (FLAGS & 2) != 0)
                shared += _neighbour_deviation(clean_ptr, b, ry, rx, -1, 1, H, W, scale_in, gain, dark, k, wd2, kf, kr, kc,
                                               f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                                               c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live & finite, (FLAGS & 2) != 0)
                shared += _neighbour_deviation(clean_ptr, b, ry, rx, 1, -1, H, W, scale_in, gain, dark, k, wd2, kf, kr, kc,
                                               f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                                               c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live & finite, (FLAGS & 2) != 0)
            s = tl.where(finite, mean + shared, s)
    elif FLAGS & 2:  # P*
        lam = s / k
        counted = k * poisson_count(lam, _key(keys_ptr, K_SHOT), _key(keys_ptr, K_SHOT_REST), _key(keys_ptr, K_SHOT_COARSE), g,
                              f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                              c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live)
        s = tl.where((lam == lam) & (tl.abs(lam) < float("inf")), counted, s)  # NaN/Inf pass through
    elif FLAGS & 4:  # P
        s += tl.sqrt(k * tl.maximum(s, 0.0)) * _normal(draw(_key(keys_ptr, K_SHOT), g))
    if FLAGS_HIGH & 256:  # (word 1) full well: a pixel holds at most K x its full well's electrons (keyed by the sensor's pixel)
        well = k * _col(v, C_WELL) * (1.0 + _col(v, C_WELLS) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_WELL_PATTERN), p)))
        s = tl.where((s == s) & (tl.abs(s) < float("inf")), tl.minimum(s, well), s)  # NaN/Inf pass through
    if FLAGS & 72057594037927936:  # charge trapping: traps of q DN take q (1 - exp(-s / q)) of a charge s > 0
        trap = _col(v, C_TRAP)
        s -= tl.where(s > 0.0, trap * (1.0 - tl.exp(-tl.maximum(s, 0.0) / tl.maximum(trap, 1e-30))), 0.0)  # 0 for trap 0
    if FLAGS & 1048576:  # gain non-linearity: the photo signal compressed, s (1 - c s) above 0 DN
        s -= tl.load(v + C_NL + c) * s * tl.maximum(s, 0.0)
    if FLAGS & 549755813888:  # frame-to-frame gain: this frame's factor on the photo signal and its shot noise
        s *= _col(v, C_FG)
    if FLAGS & 4398046511104:  # measured gain grid: its conversion share, on the photo signal and its shot noise
        s *= _grid_power(grid_gain, _col(v, C_GGCONV))
    if FLAGS & 4294967296:  # column gain: the sensor column's amplifier gain on the photo signal and its shot noise
        s *= (1.0 + _col(v, C_CGS) * _normal(draw(_key(keys_ptr, K_COLGAIN), ((sensor * 2 + col_set) * W + x).to(tl.uint64)))
              + _col(v, C_CGT) * _normal(draw(_key(keys_ptr, K_COLGAIN_FRAME), ((b.to(tl.int64) * 2 + col_set) * W + x).to(tl.uint64))))
    if FLAGS & 2199023255552:  # row gain: the sensor row's gain on the photo signal and its shot noise, fixed and this frame's
        s *= (1.0 + _col(v, C_RGF) * _normal(draw(_key(keys_ptr, K_ROWGAIN), ((sensor * 2 + row_set) * H + y).to(tl.uint64)))
              + _col(v, C_RGT) * _normal(draw(_key(keys_ptr, K_ROWGAIN_FRAME), ((b.to(tl.int64) * 2 + row_set) * H + y).to(tl.uint64))))
    if FLAGS & 288230376151711744:  # gain defect pixels: the pixel's gain on its photo signal if it is a defect (keyed by the sensor's pixel)
        s *= tl.maximum(1.0 + _defect_line(normal_ptr, _key(keys_ptr, K_PGAIN), p, _col(v, C_PGD), _col(v, C_PGM), _col(v, C_PGL),
                                           _col(v, C_PGN)), 0.0)
    if FLAGS & 144115188075855872:  # pixel gain noise: the pixel's gain this frame on its signal, new at every pixel and frame
        s *= 1.0 + _col(v, C_GNS) * _normal(draw(_key(keys_ptr, K_GAIN_NOISE), g))
    if FLAGS & 8:  # FPN: white fixed pattern + bilinear dark shading, a window (fpn_oy, fpn_ox) of fpn_h x fpn_w
        fh = _col(v, C_FH)
        fw = _col(v, C_FW)
        fh = tl.where(fh > 0.0, fh, H.to(tl.float64))
        fw = tl.where(fw > 0.0, fw, W.to(tl.float64))
        shading = _shading(grids_ptr, GH.to(tl.int64), GW.to(tl.int64), _col(v, C_FR).to(tl.int64), y.to(tl.float64) + _col(v, C_FOY),
                           x.to(tl.float64) + _col(v, C_FOX), fh, fw, _col(v, C_FGH).to(tl.int64), _col(v, C_FGW).to(tl.int64), live)
        s += _col(v, C_FS) * _normal(draw(_key(keys_ptr, K_FPN), p)) + shading
    if FLAGS_HIGH & 262144:  # (word 1) the measured fixed map: a window (fmap_oy, fmap_ox) of fmap_h x fmap_w
        mh = _col(v, C_FMH)
        mw = _col(v, C_FMW)
        mh = tl.where(mh > 0.0, mh, H.to(tl.float64))
        mw = tl.where(mw > 0.0, mw, W.to(tl.float64))
        s += _shading(grids_ptr, GH.to(tl.int64), GW.to(tl.int64), _col(v, C_FMR).to(tl.int64), y.to(tl.float64) + _col(v, C_FMOY),
                      x.to(tl.float64) + _col(v, C_FMOX), mh, mw, _col(v, C_FMGH).to(tl.int64), _col(v, C_FMGW).to(tl.int64), live)
    if FLAGS & 16:  # hot pixels
        hot = unit(draw(_key(keys_ptr, K_HOT_WHERE), p)) < _col(v, C_HD)
        size = _col(v, C_HM) * tl.exp(_col(v, C_HL) * _normal(draw(_key(keys_ptr, K_HOT_SIZE), p)))
        s += tl.where(hot, size, 0.0)
        pt = (sensor.to(tl.int64) * hw + src).to(tl.uint64)  # a hot tile: the four pixels of a 2x2 tile alike
        tile = unit(draw(_key(keys_ptr, K_HOT_TILE_WHERE), pt)) < _col(v, C_HTD)
        s += tl.where(tile, _col(v, C_HM) * tl.exp(_col(v, C_HL) * _normal(draw(_key(keys_ptr, K_HOT_TILE_SIZE), pt))), 0.0)
    if FLAGS & 134217728:  # telegraph pixels: the step, in the frames where the pixel is high
        flips = (unit(draw(_key(keys_ptr, K_RTS_WHERE), p)) < _col(v, C_RTD)) & (unit(draw(_key(keys_ptr, K_RTS_STATE), g)) < _col(v, C_RTH))
        step = _col(v, C_RTM) * tl.exp(_col(v, C_RTL) * _normal(draw(_key(keys_ptr, K_RTS_SIZE), p)))
        s += tl.where(flips, step, 0.0)
    if FLAGS & 70368744177664:  # noisy pixels: the pixel's own temporal noise, new in every frame
        noisy = unit(draw(_key(keys_ptr, K_NOISY_WHERE), p)) < _col(v, C_NZD)
        size = _col(v, C_NZM) * tl.exp(_col(v, C_NZL) * _normal(draw(_key(keys_ptr, K_NOISY_SIZE), p)))
        s += tl.where(noisy, size * _normal(draw(_key(keys_ptr, K_NOISY_READ), g)), 0.0)
    if FLAGS & 281474976710656:  # noisy columns: a sensor column's extra temporal noise, new at every pixel and frame
        q = ((sensor * 2 + col_set) * W + x).to(tl.uint64)
        noisy_col = unit(draw(_key(keys_ptr, K_NCOL_WHERE), q)) < _col(v, C_NCD)
        size = _col(v, C_NCM) * tl.exp(_col(v, C_NCL) * _normal(draw(_key(keys_ptr, K_NCOL_SIZE), q)))
        s += tl.where(noisy_col, size * _normal(draw(_key(keys_ptr, K_NCOL_READ), g)), 0.0)
    if FLAGS_HIGH & 4:  # (word 1) readout bank noise: the sensor column's bank's extra white noise, new at every pixel and frame
        bank_sigma = tl.load(v + C_BNC0 + (2 * x + col_set) % _col(v, C_BNCP).to(tl.int64), mask=live, other=0.0)
        s += bank_sigma * _normal(draw(_key(keys_ptr, K_BANK_NOISE), g))
    if FLAGS_HIGH & 16:  # (word 1) burst rows: extra white noise at every pixel of a sensor row that bursts in this frame
        burst = unit(draw(_key(keys_ptr, K_BURST_ROW), (b.to(tl.int64) * 2 * H + 2 * y + row_set).to(tl.uint64))) < _col(v, C_BRD)
        s += tl.where(burst, _col(v, C_BRS) * _normal(draw(_key(keys_ptr, K_BURST_NOISE), g)), 0.0)
    if FLAGS_HIGH & 128:  # (word 1) burst columns: extra white noise at every pixel of a sensor column that bursts in this frame
        burst_col = unit(draw(_key(keys_ptr, K_BURST_COL), (b.to(tl.int64) * 2 * W + 2 * x + col_set).to(tl.uint64))) < _col(v, C_CBD)
        s += tl.where(burst_col, _col(v, C_CBS) * _normal(draw(_key(keys_ptr, K_BURST_COL_NOISE), g)), 0.0)
    if FLAGS & 36028797018963968:  # exposure noise: white, new at every pixel and frame
        s += _col(v, C_DNS) * _normal(draw(_key(keys_ptr, K_DARK_NOISE), g))
    read_gain = 1.0
    if FLAGS & 274877906944:  # frame-to-frame read-noise level: this frame's factor on the base read noise
        read_gain = _col(v, C_RG)
    if FLAGS & 131072:  # measured read-noise quantiles on a grid of normal scores, linear between
        n1 = (READ_N - 1).to(tl.float64)
        t = tl.minimum(tl.maximum((_normal(draw(_key(keys_ptr, K_READ), g)) + Z_MAX) * (n1 / (2.0 * Z_MAX)), 0.0), n1)
        i = tl.minimum(t.to(tl.int64), READ_N - 2)
        f = t - i.to(tl.float64)
        row = read_ptr + (_col(v, C_RQ_REC).to(tl.int64) * 4 + c) * READ_N
        s += read_gain * _col(v, C_RQ_SCALE) * (tl.load(row + i, mask=live, other=0.0) * (1.0 - f) + tl.load(row + i + 1, mask=live, other=0.0) * f)
    elif FLAGS & 32:  # G*
        t, sign = tail_of(draw(_key(keys_ptr, K_READ), g))
        s += read_gain * _col(v, C_TL) * (sign * tukey_upper(t, _col(v, C_LAM).to(tl.float32))).to(tl.float64)
    elif FLAGS & 64:  # G
        s += read_gain * _col(v, C_G) * _normal(draw(_key(keys_ptr, K_READ), g))
    if FLAGS & 2097152:  # correlated read noise: one per-frame raw normal field through the kernel's taps
        kx = _key(keys_ptr, K_XTALK)
        ry = 2 * y + row_set
        rx = 2 * x + col_set
        RH = 2 * H.to(tl.int64)
        RW = 2 * W.to(tl.int64)
        s += _xtalk_tap(kx, v, 0, XT_DY0, XT_DX0, b, ry, rx, RH, RW) + _xtalk_tap(kx, v, 1, XT_DY1, XT_DX1, b, ry, rx, RH, RW)
        s += _xtalk_tap(kx, v, 2, XT_DY2, XT_DX2, b, ry, rx, RH, RW) + _xtalk_tap(kx, v, 3, XT_DY3, XT_DX3, b, ry, rx, RH, RW)
        s += _xtalk_tap(kx, v, 4, XT_DY4, XT_DX4, b, ry, rx, RH, RW) + _xtalk_tap(kx, v, 5, XT_DY5, XT_DX5, b, ry, rx, RH, RW)
        s += _xtalk_tap(kx, v, 6, XT_DY6, XT_DX6, b, ry, rx, RH, RW)
    if FLAGS & 67108864:  # shared-pixel readout: one value per frame and packed position (the tile's four pixels)
        s += _col(v, C_SH) * _normal(draw(_key(keys_ptr, K_SHARED), ((b.to(tl.int64) * H + y) * W + x).to(tl.uint64)))
    if FLAGS & 33554432:  # read-noise map: extra white read noise of the pixel's channel, row block and column block
        rmh = _col(v, C_RMH).to(tl.int64)
        rmw = _col(v, C_RMW).to(tl.int64)
        rmh = tl.where(rmh > 0, rmh, H.to(tl.int64))
        rmw = tl.where(rmw > 0, rmw, W.to(tl.int64))
        by = _block(v, C_RMYE0, (y + _col(v, C_RMOY).to(tl.int64)).to(tl.float64), rmh.to(tl.float64))
        bx = _block(v, C_RMXE0, (x + _col(v, C_RMOX).to(tl.int64)).to(tl.float64), rmw.to(tl.float64))
        sc = tl.load(v + C_RMC0 + c)
        sy = tl.load(v + C_RMY0 + by, mask=live, other=0.0)
        sx = tl.load(v + C_RMX0 + bx, mask=live, other=0.0)
        rmrec = _col(v, C_RMCR).to(tl.int64)
        at = tl.where(rmrec >= 0, (rmrec * GH.to(tl.int64) + by) * GW.to(tl.int64) + bx, 0)  # -1: no cells (read element 0)
        cell = tl.where(rmrec >= 0, tl.load(grids_ptr + at, mask=live, other=0.0), 0.0)
        s += tl.sqrt(sc * sc + sy * sy + sx * sx + cell) * _normal(draw(_key(keys_ptr, K_READ_MAP), g))
    if FLAGS & 68719476736:  # impulsive noise: a single-frame event at this pixel of this frame
        u = unit(draw(_key(keys_ptr, K_SPIKE_WHERE), g))
        hit = u < _col(v, C_SPD)
        size = _col(v, C_SPM) * tl.exp(_col(v, C_SPL) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_SPIKE_SIZE), g)))
        size = tl.where(u < _col(v, C_SPD) * _col(v, C_SPN), -size, size)  # the lowest share of the events: dark ones
        s += tl.where(hit, size, 0.0)
    if FLAGS & 137438953472:  # column telegraph noise: a telegraph column's step, in the frames where it is high
        q = ((sensor * 2 + col_set) * W + x).to(tl.uint64)
        flick = (unit(draw(_key(keys_ptr, K_CRTS_WHERE), q)) < _col(v, C_CRD)) & \
            (unit(draw(_key(keys_ptr, K_CRTS_STATE), ((b * 2 + col_set).to(tl.int64) * W + x).to(tl.uint64))) < _col(v, C_CRH))
        step = _col(v, C_CRM) * tl.exp(_col(v, C_CRL) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_CRTS_SIZE), q)))
        s += tl.where(flick, step, 0.0)
    if FLAGS & 562949953421312:  # row telegraph noise: a telegraph row's step, in the frames where it is high
        q = ((sensor * 2 + row_set) * H + y).to(tl.uint64)
        flick = (unit(draw(_key(keys_ptr, K_RRTS_WHERE), q)) < _col(v, C_RRD)) & \
            (unit(draw(_key(keys_ptr, K_RRTS_STATE), ((b * 2 + row_set).to(tl.int64) * H + y).to(tl.uint64))) < _col(v, C_RRH))
        step = _col(v, C_RRM) * tl.exp(_col(v, C_RRL) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_RRTS_SIZE), q)))
        s += tl.where(flick, step, 0.0)
    if FLAGS & 256:  # column noise: per frame and fixed
        rho = _col(v, C_CRHO)
        kc = _key(keys_ptr, K_COL)
        z = _normal(draw(kc, ((b * 2 + col_set).to(tl.int64) * W + x).to(tl.uint64)))
        if rho > 0.0:  # a sequence's frames: an AR(1) over the frames 0 .. b of the batch
            z = tl.exp(b.to(tl.float64) * tl.log(rho)) * _normal(draw(kc, (col_set.to(tl.int64) * W + x).to(tl.uint64)))
            for m in range(1, b + 1):
                z += (tl.sqrt(1.0 - rho * rho) * tl.exp((b - m).to(tl.float64) * tl.log(rho))
                      * _normal(draw(kc, ((m * 2 + col_set).to(tl.int64) * W + x).to(tl.uint64))))
        s += _col(v, C_CS) * z
        s += _col(v, C_CF) * _normal(draw(_key(keys_ptr, K_COL_PATTERN), ((sensor * 2 + col_set) * W + x).to(tl.uint64)))
    if FLAGS_HIGH & 65536:  # (word 1) column noise per tap: the sensor column's offset of this frame, its tap's std
        ctc = _tap(v, C_CTC0, C_CTOX, C_CTW, x, col_set, W)
        cts = tl.load(v + C_CTS0 + ctc)
        s += cts * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_COL_TAP), ((b * 2 + col_set).to(tl.int64) * W + x).to(tl.uint64)))
    if FLAGS_HIGH & 512:  # (word 1) column groups: the group's offset of this frame (groups of width sensor columns from start)
        width = tl.maximum(_col(v, C_CGRW).to(tl.int64), 1)
        group = ((2 * x + col_set).to(tl.int64) + width - _col(v, C_CGR0).to(tl.int64)) // width
        s += _col(v, C_CGRS) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_COL_GROUP), (b.to(tl.int64) * 2 * W + group).to(tl.uint64)))
    if FLAGS_HIGH & 1:  # (word 1) column drift: octaves of interpolated per-frame column offsets
        rx = 2 * x + col_set
        kd = _key(keys_ptr, K_COL_DRIFT)
        kp = _key(keys_ptr, K_COL_DRIFT_PHASE)
        cd = tl.zeros_like(s)
        for j in tl.static_range(OCT):
            cd += _drift_octave(kd, kp, normal_ptr, v, C_CDR0, 0, j, b, rx)
        s += cd
    if FLAGS & 1073741824:  # column banding: tones along the sensor columns, a phase per frame and tone
        rx = 2 * x + col_set
        kc = _key(keys_ptr, K_COL_BAND)
        s += _tone(kc, v, 0, b, rx, C_CBF0, C_CBA0) + _tone(kc, v, 1, b, rx, C_CBF0, C_CBA0) + _tone(kc, v, 2, b, rx, C_CBF0, C_CBA0)
    if FLAGS & 8589934592:  # diagonal banding: tones along both axes, a phase per frame and tone, and the sensor's
        ry = 2 * y + row_set
        rx = 2 * x + col_set
        kd = _key(keys_ptr, K_DIAG_BAND)
        s += _diag_tone(kd, v, 0, b, sensor, ry, rx) + _diag_tone(kd, v, 1, b, sensor, ry, rx) + _diag_tone(kd, v, 2, b, sensor, ry, rx)
    if FLAGS & 262144:  # defect lines: the sensor column's offset here, the row's below
        cline = ((sensor * 2 + col_set) * W + x).to(tl.uint64)
        s += (_defect_line(normal_ptr, _key(keys_ptr, K_LINES_COL), cline, _col(v, C_LCD), _col(v, C_LM), _col(v, C_LLS), _col(v, C_LNEG))
              * _line_part(_key(keys_ptr, K_LINES_COL_CUT), cline, _col(v, C_LPART), _col(v, C_LEND), _col(v, C_LCLO),
                           _col(v, C_LCHI), 2 * y + row_set, 2.0 * H))
    if FLAGS & 1099511627776:  # measured line profiles: the column's offset here, the row's below (a larger input repeats them)
        lm = grids_ptr + _col(v, C_LMR).to(tl.int64) * GH.to(tl.int64) * GW.to(tl.int64)
        lx = (x + _col(v, C_LMOX).to(tl.int64)) % _col(v, C_LMLW).to(tl.int64)
        s += tl.load(lm + (4 + c).to(tl.int64) * GW.to(tl.int64) + lx, mask=live, other=0.0)
    if FLAGS & 4611686018427387904:  # readout bank offsets: the sensor column's bank, the row's below
        s += tl.load(v + C_BKC0 + (2 * x + col_set) % _col(v, C_BKCP).to(tl.int64), mask=live, other=0.0)
    if FLAGS & 512:  # U
        s += (unit(draw(_key(keys_ptr, K_QUANT), g)) - 0.5) * _col(v, C_Q)
    if FLAGS & 32768:  # measured low-frequency field: a per-frame normal grid, bilinear
        gh = _col(v, C_LF_GH).to(tl.int64)
        gw = _col(v, C_LF_GW).to(tl.int64)
        s += _col(v, C_LF) * _normal_grid(normal_ptr, _key(keys_ptr, K_LOWFREQ), b.to(tl.int64) * gh, y, x, H, W, gh, gw)
    if FLAGS & 1152921504606846976:  # measured fixed field: the sensor's normal grid, bilinear
        fgh = _col(v, C_FF_GH).to(tl.int64)
        fgw = _col(v, C_FF_GW).to(tl.int64)
        s += _col(v, C_FF) * _normal_grid(normal_ptr, _key(keys_ptr, K_FFIELD), sensor.to(tl.int64) * fgh, y, x, H, W, fgh, fgw)
    line = 0.0
    if FLAGS & 128:  # R: one offset per sensor row
        z_row = _normal(draw(_key(keys_ptr, K_ROW), ((b * 2 + row_set).to(tl.int64) * H + y).to(tl.uint64)))
        if FLAGS & 576460752303423488:  # heavy-tailed row noise: Tukey's h transform, scaled back to unit variance
            h_row = _col(v, C_RH)
            z_row *= tl.exp(0.5 * h_row * z_row * z_row) * tl.exp(0.75 * tl.log(1.0 - 2.0 * h_row))
        line += _col(v, C_R) * z_row
    if FLAGS_HIGH & 32:  # (word 1) row-noise map: the row block's own row noise, per sensor row and frame
        rwh = tl.where(_col(v, C_RWH) > 0.0, _col(v, C_RWH), H * 1.0).to(tl.int64)
        by = tl.minimum((y + _col(v, C_RWOY).to(tl.int64)) * NB // rwh, NB - 1)
        line += (tl.load(v + C_RWY0 + by, mask=live, other=0.0)
                 * _normal(draw(_key(keys_ptr, K_ROW_MAP), ((b * 2 + row_set).to(tl.int64) * H + y).to(tl.uint64))))
    if FLAGS_HIGH & 64:  # (word 1) row glitches: the whole sensor row offset in this frame
        q = b.to(tl.int64) * 2 * H + 2 * y + row_set
        kw = _key(keys_ptr, K_RSPIKE_WHERE)
        size = _col(v, C_RSM) * tl.exp(_col(v, C_RSL) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_RSPIKE_SIZE), q.to(tl.uint64))))
        size = tl.where(unit(draw(kw, (2 * q + 1).to(tl.uint64))) < _col(v, C_RSN), -size, size)
        line += tl.where(unit(draw(kw, (2 * q).to(tl.uint64))) < _col(v, C_RSD), size, 0.0)
    if FLAGS_HIGH & 4096:  # (word 1) exposure row noise: the sensor row's offset of this frame
        line += _col(v, C_DRN) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_DARK_ROW_NOISE), ((b * 2 + row_set).to(tl.int64) * H + y).to(tl.uint64)))
    if FLAGS_HIGH & 2048:  # (word 1) row pairs: the pair's shared offset of this frame (packed row y holds the pair)
        line += _col(v, C_RPAIR) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_ROW_PAIR), (b.to(tl.int64) * H + y).to(tl.uint64)))
    if FLAGS_HIGH & 1024:  # (word 1) black ramps: this frame's slope down the sensor rows, about the middle row
        ry_mid = (2 * y + row_set).to(tl.float64) - (2 * H - 1) * 0.5
        line += _col(v, C_RAMP_ROW) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_BLACK_RAMP), (2 * b).to(tl.uint64))) * ry_mid
    if FLAGS_HIGH & 16384:  # (word 1) black steps: this frame's step, from its row on
        line += tl.where((2 * y + row_set).to(tl.float64) >= _col(v, C_BSTEP_AT) * (2 * H), _col(v, C_BSTEP_DN), 0.0)
    if FLAGS & 4194304:  # banding: tones along the sensor rows, a phase per frame and tone
        ry = 2 * y + row_set
        kb = _key(keys_ptr, K_BAND)
        line += _tone(kb, v, 0, b, ry, C_BF0, C_BA0) + _tone(kb, v, 1, b, ry, C_BF0, C_BA0) + _tone(kb, v, 2, b, ry, C_BF0, C_BA0)
    if FLAGS & 16777216:  # row noise of each channel's own: per packed row and frame
        line += _col(v, C_RC) * _normal(draw(_key(keys_ptr, K_ROW_CHANNEL), ((plane.to(tl.int64)) * H + y).to(tl.uint64)))
    if FLAGS & 536870912:  # row drift: octaves of interpolated per-frame row offsets
        ry = 2 * y + row_set
        kd = _key(keys_ptr, K_ROW_DRIFT)
        kp = _key(keys_ptr, K_ROW_DRIFT_PHASE)
        for j in tl.static_range(OCT):
            line += _drift_octave(kd, kp, normal_ptr, v, C_DR0, 1, j, b, ry)
    if FLAGS & 8388608:  # fixed row pattern: the sensor row's offset, the same in every frame
        line += _col(v, C_RF) * _normal(draw(_key(keys_ptr, K_ROW_PATTERN), ((sensor * 2 + row_set) * H + y).to(tl.uint64)))
    if FLAGS & 262144:  # defect lines: the sensor row's offset
        rline = ((sensor * 2 + row_set) * H + y).to(tl.uint64)
        line += (_defect_line(normal_ptr, _key(keys_ptr, K_LINES_ROW), rline, _col(v, C_LRD), _col(v, C_LM), _col(v, C_LLS), _col(v, C_LNEG))
                 * _line_part(_key(keys_ptr, K_LINES_ROW_CUT), rline, _col(v, C_LPART), _col(v, C_LEND), _col(v, C_LCLO),
                              _col(v, C_LCHI), 2 * x + col_set, 2.0 * W))
    if FLAGS & 1099511627776:  # measured line profiles: the row's offset
        lm = grids_ptr + _col(v, C_LMR).to(tl.int64) * GH.to(tl.int64) * GW.to(tl.int64)
        ly = (y + _col(v, C_LMOY).to(tl.int64)) % _col(v, C_LMLH).to(tl.int64)
        line += tl.load(lm + c.to(tl.int64) * GW.to(tl.int64) + ly, mask=live, other=0.0)
    if FLAGS & 4611686018427387904:  # readout bank offsets: the sensor row's bank
        line += tl.load(v + C_BKR0 + (2 * y + row_set) % _col(v, C_BKRP).to(tl.int64), mask=live, other=0.0)
    if FLAGS & 1024:  # C
        line += tl.load(v + C_B0 + c)
    if FLAGS & 2048:  # BLE
        line += _col(v, C_BS) * _normal(draw(_key(keys_ptr, K_BLE), (b * 5).to(tl.uint64) + tl.zeros_like(g)))
        line += _col(v, C_BC) * _normal(draw(_key(keys_ptr, K_BLE), (b * 5 + 1 + c).to(tl.uint64) + tl.zeros_like(g)))
    if FLAGS & 34359738368:  # black level moving with exposure
        line += _col(v, C_DOFF)
    if FLAGS & 8796093022208:  # black level drifting over the frames of a sequence
        line += _col(v, C_DRIFT)
    if FLAGS & 4503599627370496:  # gain defect lines: the pixel's row's and column's gain if they are defects, on its signal and noise
        grow = _defect_line(normal_ptr, _key(keys_ptr, K_LGAIN_ROW), ((sensor * 2 + row_set) * H + y).to(tl.uint64),
                            _col(v, C_LGRD), _col(v, C_LGM), _col(v, C_LGLS), _col(v, C_LGNEG))
        gcol = _defect_line(normal_ptr, _key(keys_ptr, K_LGAIN_COL), ((sensor * 2 + col_set) * W + x).to(tl.uint64),
                            _col(v, C_LGCD), _col(v, C_LGM), _col(v, C_LGLS), _col(v, C_LGNEG))
        s *= tl.maximum(1.0 + grow, 0.0) * tl.maximum(1.0 + gcol, 0.0)
    if FLAGS & 2251799813685248:  # readout taps' gains: the pixel's tap's gain on its signal and noise (not the rows' and black levels' offsets)
        tr = _tap(v, C_TGR0, C_TGOY, C_TGH, y, row_set, H)
        tc = _tap(v, C_TGC0, C_TGOX, C_TGW, x, col_set, W)
        tg = grids_ptr + _col(v, C_TGR).to(tl.int64) * GH.to(tl.int64) * GW.to(tl.int64)
        s *= tl.load(tg + tr * GW.to(tl.int64) + tc, mask=live, other=1.0)
    s += line
    if FLAGS_HIGH & 1024:  # (word 1) black ramps: this frame's slope across the sensor columns, about the middle column
        rx_mid = (2 * x + col_set).to(tl.float64) - (2 * W - 1) * 0.5
        s += _col(v, C_RAMP_COL) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_BLACK_RAMP), (2 * b + 1).to(tl.uint64))) * rx_mid
    if FLAGS_HIGH & 8192:  # (word 1) row noise per column tap: the sensor row's offset of this frame in the pixel's tap
        rtc = _tap(v, C_RTC0, C_RTOX, C_RTW, x, col_set, W)
        rtq = ((b * 2 + row_set).to(tl.int64) * H + y) * (TPE + 1) + rtc
        s += _col(v, C_RTS) * symmetric_table(normal_ptr, draw(_key(keys_ptr, K_ROW_TAP), rtq.to(tl.uint64)))
    if FLAGS & 1125899906842624:  # readout taps: this frame's offset of the pixel's tap
        tr = _tap(v, C_TPR0, C_TPOY, C_TPH, y, row_set, H)
        tc = _tap(v, C_TPC0, C_TPOX, C_TPW, x, col_set, W)
        tap = (b.to(tl.int64) * (TPE + 1) + tr) * (TPE + 1) + tc
        s += _col(v, C_TPS) * _normal(draw(_key(keys_ptr, K_TAP), tap.to(tl.uint64)))
    if FLAGS & 18014398509481984:  # ADC non-linearity: the code whose decision levels hold s
        code = tl.floor(s + 0.5)
        finite = live & (s == s) & (tl.abs(s) < float("inf"))
        period = _col(v, C_DNL_P).to(tl.int64)
        j = ((tl.where(finite, code, 0.0).to(tl.int64) % period) + period) % period
        lo = code - 0.5 + tl.load(v + C_DNL_E0 + j, mask=finite, other=0.0)
        hi = code + 0.5 + tl.load(v + C_DNL_E0 + (j + 1) % period, mask=finite, other=0.0)
        code = tl.where(s < lo, code - 1.0, tl.where(s >= hi, code + 1.0, code))
        s = tl.where(finite, code, s)
    if FLAGS & 65536:  # measured code map: nearest code the camera uses
        code = tl.floor(s + 0.5)
        rec = tl.load(v + C_CM_REC0 + c).to(tl.int64)  # the channel's map (-1: none, rounded only)
        head = code_ptr + tl.maximum(rec, 0) * (4 * CODE_N) + 3 * CODE_N  # its first code, length, period, comb bounds
        cm_lo = tl.load(head)
        cm_n = tl.where(rec >= 0, tl.load(head + 1), 0.0).to(tl.int64)
        period = tl.where(rec >= 0, tl.load(head + 2), 0.0).to(tl.int64)
        i = (code - cm_lo).to(tl.int64)
        inside = live & (i >= 0) & (i < cm_n)
        comb = (code >= tl.load(head + 3)) & (code <= tl.load(head + 4))  # its bounds
        periodic = live & ~inside & comb & ((tl.zeros_like(i) + period) > 0)  # a periodic comb goes on beyond the measured range
        j = ((i % tl.maximum(period, 1)) + tl.maximum(period, 1)) % tl.maximum(period, 1)
        at = tl.where(inside, i, j)  # the map's entry: the code's own, or its phase's in the first period
        row = code_ptr + tl.maximum(rec, 0) * (4 * CODE_N) + at
        used = inside | periodic
        split = tl.load(row + 2 * CODE_N, mask=used, other=0.5)
        upper = (s - code) >= split  # the code above the split (an ADC's decision level inside a missing code's cell)
        mapped = tl.where(upper, tl.load(row + CODE_N, mask=used, other=0.0), tl.load(row, mask=used, other=0.0))
        shift = mapped - (cm_lo + j.to(tl.float64))
        s = tl.where(inside, mapped, tl.where(periodic, code + shift, code))
    if FLAGS & 268435456:  # dead pixels: the stuck level, whatever came before
        dead = unit(draw(_key(keys_ptr, K_DEAD_WHERE), p)) < _col(v, C_DD)
        which = tl.minimum((unit(draw(_key(keys_ptr, K_DEAD_LEVEL), p)) * NDL).to(tl.int64), NDL - 1)
        # a dead line's part (a column's first, then a row's), where the pixel itself is not dead
        slot = _dead_line_slot(_key(keys_ptr, K_DEAD_COL), ((sensor * 2 + col_set) * W + x).to(tl.uint64), _col(v, C_DCOL),
                               _col(v, C_DPART), _col(v, C_DEND), _col(v, C_DCLO), _col(v, C_DCHI), 2 * y + row_set, 2 * H)
        slot = tl.where(slot < 0, _dead_line_slot(_key(keys_ptr, K_DEAD_ROW), ((sensor * 2 + row_set) * H + y).to(tl.uint64),
                                                  _col(v, C_DROW), _col(v, C_DPART), _col(v, C_DEND), _col(v, C_DCLO),
                                                  _col(v, C_DCHI), 2 * x + col_set, 2 * W), slot)
        which = tl.where(dead, which, slot)
        dead = dead | (slot >= 0)
        s = tl.where(dead, tl.load(v + C_DL0 + which, mask=live, other=0.0), s)
    if FLAGS & 2305843009213693952:  # stuck ADC bits: the raw code the converter writes, its stuck bits cleared or set
        zero = tl.load(v + C_SBZ0 + c)
        finite = live & (s == s) & (tl.abs(s) < float("inf"))
        code = tl.where(finite, tl.floor(s + 0.5) + zero, 0.0).to(tl.int64)
        low = _col(v, C_SBLO).to(tl.int64)
        code = (code - (code & low)) | _col(v, C_SBHI).to(tl.int64)
        s = tl.where(finite, code.to(tl.float64) - zero, s)
    if FLAGS & 4096:  # black clip
        s = tl.maximum(s, _col(v, C_CL))
    if FLAGS & 8192:  # white clip
        s = tl.minimum(s, span)
    tl.store(out_ptr + plane.to(tl.int64) * hw + idx, (s * (ratio / span)).to(out_ptr.dtype.element_ty), mask=live)


def launch(clean, out, values, keys, span, flags, fine, coarse, grids, normal, code_lut, read_lut, block: int | None = None,
           num_warps: int = 4):
    """One launch over a contiguous (B, 4, H, W) batch; tables and grids on clean's device.
    ``block`` elements per program; by default 128 on a GPU (with 4 warps 2.9x (G*+P*+R+U) to
    4.6x (a loop profile) faster than 1024 on an H100, benchmarks/results_h100/blocks.txt)
    and 1024 on CPU tensors (the interpreter: fewer, wider programs). The noise does not
    depend on it."""
    if block is None:
        block = 1024 if clean.device.type == "cpu" else 128
    b, _, h, w = clean.shape
    if b == 0 or h * w == 0:
        return out
    grid = (triton.cdiv(h * w, block), b * 4)
    fused_kernel[grid](clean, out, values, keys, float(span), h, w, *fine, *coarse, grids, grids.shape[1], grids.shape[2], normal, code_lut, code_lut.shape[-1],
                       read_lut, read_lut.shape[1],
                       FLAGS=L.flag_words(int(flags))[0], FLAGS_HIGH=L.flag_words(int(flags))[1], P=values.shape[1], BLOCK=block, num_warps=num_warps)
    return out
