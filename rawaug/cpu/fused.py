"""The whole noise chain in one pass over a CPU batch (numba).

Each element is read once, taken through every enabled stage in physical order (the
flags of ``rawaug.engine.layout``) and written once. A row is held in a buffer of its own
and taken through the stages one loop along it each, so a stage's flag is tested once per
row, not per element (2x faster with a few stages on); every element meets the same
operations in the same order, so the noise is bit for bit the one-pass loop's. Every
random number is ``rawaug.rng``'s counter hash of its stream key and the element's index,
so the result does not depend on how rows are split over threads and equals the Triton
kernel's.
Gaussian and Tukey-lambda values come from the quantile tables of ``quantile_table``
(the Triton kernel evaluates the same quantiles in registers).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..engine import layout as L
from .counter import draw, unit
from .poisson import COARSE_MAX, GRID_STEP, SPARE_BITS, TABLE_MAX, _ptrs, _small_poisson, _table_count
from .quantile_table import symmetric

_K, _PRNU = L.COLUMN["k"], L.COLUMN["prnu_sigma"]
_TL, _G, _R = L.COLUMN["sigma_tl"], L.COLUMN["sigma_g"], L.COLUMN["sigma_r"]
_CS, _CF, _CRHO = L.COLUMN["col_sigma"], L.COLUMN["col_fixed"], L.COLUMN["col_rho"]
_FS, _FR = L.COLUMN["fpn_sigma"], L.COLUMN["fpn_record"]
_SENSOR = L.COLUMN["sensor"]
_FOY, _FOX, _FH, _FW = L.COLUMN["fpn_oy"], L.COLUMN["fpn_ox"], L.COLUMN["fpn_h"], L.COLUMN["fpn_w"]
_HD, _HM, _HL = L.COLUMN["hot_density"], L.COLUMN["hot_median"], L.COLUMN["hot_log_std"]
_Q, _B0 = L.COLUMN["step_dn"], L.COLUMN["bias_r"]
_BS, _BC, _CL = L.COLUMN["ble_sigma"], L.COLUMN["ble_channel_sigma"], L.COLUMN["clip_floor"]
_RATIO = L.COLUMN["ratio"]
_DARK_E, _DSNU_LOG, _DARK_C0 = L.COLUMN["dark_e"], L.COLUMN["dsnu_log"], L.COLUMN["dark_c0"]
_DSNU_PATTERN = L.STREAM["dsnu_pattern"]
_LF, _LF_GH, _LF_GW = L.COLUMN["lowfreq_sigma"], L.COLUMN["lowfreq_gh"], L.COLUMN["lowfreq_gw"]
_CM_REC0 = L.COLUMN["codemap_record_c0"]  # channel c's record: _CM_REC0 + c
_RQ_REC, _RQ_SCALE = L.COLUMN["readq_record"], L.COLUMN["readq_scale"]
_LRD, _LCD, _LM, _LLS, _LNEG = (L.COLUMN["lines_row_density"], L.COLUMN["lines_col_density"], L.COLUMN["lines_median"],
                                L.COLUMN["lines_log_std"], L.COLUMN["lines_negative"])
_LINES_ROW, _LINES_COL = L.STREAM["lines_row"], L.STREAM["lines_col"]
_LPART, _LEND, _LCLO, _LCHI = L.COLUMN["lines_partial"], L.COLUMN["lines_to_end"], L.COLUMN["lines_cut_lo"], L.COLUMN["lines_cut_hi"]
_LINES_ROW_CUT, _LINES_COL_CUT = L.STREAM["lines_row_cut"], L.STREAM["lines_col_cut"]
_FGH, _FGW = L.COLUMN["fpn_gh"], L.COLUMN["fpn_gw"]
_GLS, _GLR, _GLOY, _GLOX = L.COLUMN["glow_s"], L.COLUMN["glow_record"], L.COLUMN["glow_oy"], L.COLUMN["glow_ox"]
_GLH, _GLW, _GLGH, _GLGW = L.COLUMN["glow_h"], L.COLUMN["glow_w"], L.COLUMN["glow_gh"], L.COLUMN["glow_gw"]
_NL, _TRAP = L.COLUMN["nl_c0"], L.COLUMN["trap_dn"]
Z_MAX = L.READ_TABLE_Z
_LOWFREQ = L.STREAM["lowfreq"]
_ROW = L.STREAM["row"]
_BLE = L.STREAM["ble"]
_PRNU_PATTERN = L.STREAM["prnu_pattern"]
_SHOT = L.STREAM["shot"]
_SHOT_REST = L.STREAM["shot_rest"]
_SHOT_COARSE = L.STREAM["shot_coarse"]
_FPN_PATTERN = L.STREAM["fpn_pattern"]
_HOT_WHERE = L.STREAM["hot_where"]
_HOT_SIZE = L.STREAM["hot_size"]
_READ = L.STREAM["read"]
_COL = L.STREAM["col"]
_COL_PATTERN = L.STREAM["col_pattern"]
_QUANT = L.STREAM["quant"]
_XT0 = L.COLUMN["xt_0"]
_BF0, _BA0 = L.COLUMN["band_f0"], L.COLUMN["band_a0"]
_BAND = L.STREAM["band"]
_CBF0, _CBA0 = L.COLUMN["cband_f0"], L.COLUMN["cband_a0"]
_DHD, _DHE, _DHL = L.COLUMN["dhot_density"], L.COLUMN["dhot_e"], L.COLUMN["dhot_log_std"]
_DHOT_WHERE, _DHOT_SIZE = L.STREAM["dhot_where"], L.STREAM["dhot_size"]
_CGS, _COLGAIN_PATTERN = L.COLUMN["colgain_sigma"], L.STREAM["colgain_pattern"]
_CGT, _COLGAIN_FRAME = L.COLUMN["colgain_frame"], L.STREAM["colgain_frame"]
_DSNU_COL, _DSNU_COL_PATTERN = L.COLUMN["dsnu_col_log"], L.STREAM["dsnu_col_pattern"]
_DSNU_ROW, _DSNU_ROW_PATTERN = L.COLUMN["dsnu_row_log"], L.STREAM["dsnu_row_pattern"]
_RGF, _RGT = L.COLUMN["rowgain_fixed"], L.COLUMN["rowgain_frame"]
_ROWGAIN_PATTERN, _ROWGAIN_FRAME = L.STREAM["rowgain_pattern"], L.STREAM["rowgain_frame"]
_DCD, _DCE, _DCL = L.COLUMN["dcol_density"], L.COLUMN["dcol_e"], L.COLUMN["dcol_log_std"]
_DCOL_WHERE, _DCOL_SIZE = L.STREAM["dcol_where"], L.STREAM["dcol_size"]
_DRD, _DRE, _DRL = L.COLUMN["drow_density"], L.COLUMN["drow_e"], L.COLUMN["drow_log_std"]
_DROW_WHERE, _DROW_SIZE = L.STREAM["drow_where"], L.STREAM["drow_size"]
_NZD, _NZM, _NZL = L.COLUMN["noisy_density"], L.COLUMN["noisy_median"], L.COLUMN["noisy_log_std"]
_NOISY_WHERE, _NOISY_SIZE, _NOISY_READ = L.STREAM["noisy_where"], L.STREAM["noisy_size"], L.STREAM["noisy_read"]
_TDD, _TDE, _TDL, _TDH = L.COLUMN["drts_density"], L.COLUMN["drts_e"], L.COLUMN["drts_log_std"], L.COLUMN["drts_high"]
_DRTS_WHERE, _DRTS_SIZE, _DRTS_STATE = L.STREAM["drts_where"], L.STREAM["drts_size"], L.STREAM["drts_state"]
_NCD, _NCM, _NCL = L.COLUMN["ncol_density"], L.COLUMN["ncol_median"], L.COLUMN["ncol_log_std"]
_NCOL_WHERE, _NCOL_SIZE, _NCOL_READ = L.STREAM["ncol_where"], L.STREAM["ncol_size"], L.STREAM["ncol_read"]
_RRD, _RRM, _RRL, _RRH = L.COLUMN["rrts_density"], L.COLUMN["rrts_median"], L.COLUMN["rrts_log_std"], L.COLUMN["rrts_high"]
_RRTS_WHERE, _RRTS_SIZE, _RRTS_STATE = L.STREAM["rrts_where"], L.STREAM["rrts_size"], L.STREAM["rrts_state"]
_TPS, _TPC0, _TPR0 = L.COLUMN["tap_sigma"], L.COLUMN["tap_c0"], L.COLUMN["tap_r0"]
_TPOY, _TPOX, _TPH, _TPW, _TAP = L.COLUMN["tap_oy"], L.COLUMN["tap_ox"], L.COLUMN["tap_h"], L.COLUMN["tap_w"], L.STREAM["tap"]
_TPE = L.TAP_EDGES
_LGRD, _LGCD, _LGM, _LGLS, _LGNEG = (L.COLUMN[n] for n in ("lgain_row_density", "lgain_col_density", "lgain_median", "lgain_log_std", "lgain_negative"))
_LGAIN_ROW, _LGAIN_COL = L.STREAM["lgain_row"], L.STREAM["lgain_col"]
_DDF = L.COLUMN["dark_factor"]
_DNS, _DARK_NOISE = L.COLUMN["dark_noise"], L.STREAM["dark_noise"]
_GNS, _GAIN_NOISE = L.COLUMN["gain_noise"], L.STREAM["gain_noise"]
_PGD, _PGM, _PGL, _PGN = (L.COLUMN[n] for n in ("pgain_density", "pgain_median", "pgain_log_std", "pgain_negative"))
_PGAIN = L.STREAM["pgain"]
_RH = L.COLUMN["row_h"]
_FF, _FF_GH, _FF_GW, _FFIELD = L.COLUMN["ffield_sigma"], L.COLUMN["ffield_gh"], L.COLUMN["ffield_gw"], L.STREAM["ffield"]
_DNL_P, _DNL_E0 = L.COLUMN["dnl_period"], L.COLUMN["dnl_e0"]
_TGR, _TGC0, _TGR0 = L.COLUMN["tgain_record"], L.COLUMN["tgain_c0"], L.COLUMN["tgain_r0"]
_TGOY, _TGOX, _TGH, _TGW = L.COLUMN["tgain_oy"], L.COLUMN["tgain_ox"], L.COLUMN["tgain_h"], L.COLUMN["tgain_w"]
_TAPS = _TPE + 1
_DOFF = L.COLUMN["dark_offset"]
_DRIFT = L.COLUMN["black_drift"]
_RG = L.COLUMN["read_gain"]
_FG = L.COLUMN["frame_gain"]
_LMR, _LMOY, _LMOX, _LMLH, _LMLW = (L.COLUMN[n] for n in ("lmap_record", "lmap_oy", "lmap_ox", "lmap_lh", "lmap_lw"))
_GGR, _GGPY, _GGPX, _GGOY, _GGOX = (L.COLUMN[n] for n in ("ggrid_record", "ggrid_py", "ggrid_px", "ggrid_oy", "ggrid_ox"))
_GGCONV = L.COLUMN["ggrid_conv"]
_SPD, _SPM, _SPL, _SPN = (L.COLUMN[n] for n in ("spike_density", "spike_median", "spike_log_std", "spike_negative"))
_SPIKE_WHERE, _SPIKE_SIZE = L.STREAM["spike_where"], L.STREAM["spike_size"]
_CRD, _CRM, _CRL, _CRH = L.COLUMN["crts_density"], L.COLUMN["crts_median"], L.COLUMN["crts_log_std"], L.COLUMN["crts_high"]
_CRTS_WHERE, _CRTS_SIZE, _CRTS_STATE = L.STREAM["crts_where"], L.STREAM["crts_size"], L.STREAM["crts_state"]
_DBX0, _DBY0, _DBA0, _DBF0 = L.COLUMN["dband_fx0"], L.COLUMN["dband_fy0"], L.COLUMN["dband_a0"], L.COLUMN["dband_f0"]
_FIXED_PHASE = L.FIXED_PHASE
_DIAG_BAND = L.STREAM["diag_band"]
_COL_BAND = L.STREAM["col_band"]
_RF, _ROW_PATTERN = L.COLUMN["rowfix_sigma"], L.STREAM["row_pattern"]
_RC, _ROW_CHANNEL = L.COLUMN["rowch_sigma"], L.STREAM["row_channel"]
_TONES = L.BAND_TONES
_RMC0, _RMY0, _RMX0 = L.COLUMN["rmap_c0"], L.COLUMN["rmap_y0"], L.COLUMN["rmap_x0"]
_RMOY, _RMOX, _RMH, _RMW = L.COLUMN["rmap_oy"], L.COLUMN["rmap_ox"], L.COLUMN["rmap_h"], L.COLUMN["rmap_w"]
_RMYE0, _RMXE0, _RMCR = L.COLUMN["rmap_ye0"], L.COLUMN["rmap_xe0"], L.COLUMN["rmap_cell_record"]
_READ_MAP, _NB = L.STREAM["read_map"], L.READ_MAP_BLOCKS
_SH, _SHARED = L.COLUMN["shared_sigma"], L.STREAM["shared"]
_RTD, _RTM, _RTL, _RTH = L.COLUMN["rts_density"], L.COLUMN["rts_median"], L.COLUMN["rts_log_std"], L.COLUMN["rts_high"]
_RTS_WHERE, _RTS_SIZE, _RTS_STATE = L.STREAM["rts_where"], L.STREAM["rts_size"], L.STREAM["rts_state"]
_DD, _DL0, _NDL = L.COLUMN["dead_density"], L.COLUMN["dead_l0"], L.DEAD_LEVELS
_SBZ0, _SBLO, _SBHI = L.COLUMN["stuck_z0"], L.COLUMN["stuck_low"], L.COLUMN["stuck_high"]
_BKCP, _BKRP, _BKC0, _BKR0 = L.COLUMN["bank_cp"], L.COLUMN["bank_rp"], L.COLUMN["bank_c0"], L.COLUMN["bank_r0"]
_DEAD_WHERE, _DEAD_LEVEL = L.STREAM["dead_where"], L.STREAM["dead_level"]
_DCOL, _DROW, _DPART, _DEND = L.COLUMN["dead_col_density"], L.COLUMN["dead_row_density"], L.COLUMN["dead_partial"], L.COLUMN["dead_to_end"]
_DEAD_COL, _DEAD_ROW = L.STREAM["dead_col"], L.STREAM["dead_row"]
_DCLO, _DCHI = L.COLUMN["dead_cut_lo"], L.COLUMN["dead_cut_hi"]
_DR0, _OCT = L.COLUMN["drift_a0"], L.DRIFT_OCTAVES
_ROW_DRIFT, _ROW_DRIFT_PHASE = L.STREAM["row_drift"], L.STREAM["row_drift_phase"]
_CDR0, _COL_DRIFT, _COL_DRIFT_PHASE = L.COLUMN["cdrift_a0"], L.STREAM["col_drift"], L.STREAM["col_drift_phase"]
_COL_DRIFT_HIGH = L.COL_DRIFT >> L.WORD_BITS  # its bit in stage-flag word 1
_RPD, _ROW_REPEAT, _CHAIN = L.COLUMN["repeat_density"], L.STREAM["row_repeat"], L.REPEAT_CHAIN
_ROW_REPEAT_HIGH = L.ROW_REPEAT >> L.WORD_BITS
_BNCP, _BNC0, _BANK_NOISE = L.COLUMN["bnoise_cp"], L.COLUMN["bnoise_c0"], L.STREAM["bank_noise"]
_BANK_NOISE_HIGH = L.BANK_NOISE >> L.WORD_BITS
_CLD, _CLE, _CLL, _CLS = L.COLUMN["dclus_density"], L.COLUMN["dclus_e"], L.COLUMN["dclus_log_std"], L.COLUMN["dclus_size"]
_DCLUS_WHERE, _DCLUS_SIZE = L.STREAM["dclus_where"], L.STREAM["dclus_size"]
_DARK_CLUSTER_HIGH = L.DARK_CLUSTER >> L.WORD_BITS
_BRD, _BRS, _BURST_ROW, _BURST_NOISE = L.COLUMN["burst_density"], L.COLUMN["burst_sigma"], L.STREAM["burst_row"], L.STREAM["burst_noise"]
_ROW_BURST_HIGH = L.ROW_BURST >> L.WORD_BITS
_CBD, _CBS, _BURST_COL, _BURST_COL_NOISE = L.COLUMN["cburst_density"], L.COLUMN["cburst_sigma"], L.STREAM["burst_col"], L.STREAM["burst_col_noise"]
_COL_BURST_HIGH = L.COL_BURST >> L.WORD_BITS
_DRN, _DARK_ROW_NOISE, _DARK_ROW_NOISE_HIGH = L.COLUMN["dark_row_sigma"], L.STREAM["dark_row_noise"], L.DARK_ROW_NOISE >> L.WORD_BITS
_RPAIR, _ROW_PAIR, _ROW_PAIR_HIGH = L.COLUMN["rpair_sigma"], L.STREAM["row_pair"], L.ROW_PAIR >> L.WORD_BITS
_RTS, _RTC0, _RTOX, _RTW = L.COLUMN["rtap_sigma"], L.COLUMN["rtap_c0"], L.COLUMN["rtap_ox"], L.COLUMN["rtap_w"]
_ROW_TAP, _ROW_TAP_HIGH = L.STREAM["row_tap"], L.ROW_TAP >> L.WORD_BITS
_CTS0, _CTC0, _CTOX, _CTW = L.COLUMN["ctap_s0"], L.COLUMN["ctap_c0"], L.COLUMN["ctap_ox"], L.COLUMN["ctap_w"]
_COL_TAP, _COL_TAP_HIGH = L.STREAM["col_tap"], L.COL_TAP >> L.WORD_BITS
_RAMP_ROW, _RAMP_COL, _BLACK_RAMP, _BLACK_RAMP_HIGH = L.COLUMN["ramp_row"], L.COLUMN["ramp_col"], L.STREAM["black_ramp"], L.BLACK_RAMP >> L.WORD_BITS
_BSTEP_AT, _BSTEP_DN, _BLACK_STEP_HIGH = L.COLUMN["bstep_at"], L.COLUMN["bstep_dn"], L.BLACK_STEP >> L.WORD_BITS
_MASK_T, _MASK_B, _MASK_L, _MASK_R, _MASKED_HIGH = (L.COLUMN["mask_top"], L.COLUMN["mask_bottom"], L.COLUMN["mask_left"],
                                                   L.COLUMN["mask_right"], L.MASKED >> L.WORD_BITS)
_CGRS, _CGRW, _CGR0, _COL_GROUP, _COL_GROUP_HIGH = L.COLUMN["cgroup_sigma"], L.COLUMN["cgroup_width"], L.COLUMN["cgroup_start"], L.STREAM["col_group"], L.COL_GROUP >> L.WORD_BITS
_WELL, _WELL_SPREAD, _WELL_PATTERN, _FULL_WELL_HIGH = L.COLUMN["well_e"], L.COLUMN["well_spread"], L.STREAM["well_pattern"], L.FULL_WELL >> L.WORD_BITS
_ROWMAP_Y0, _ROWMAP_OY, _ROWMAP_H, _ROW_MAP = L.COLUMN["rowmap_y0"], L.COLUMN["rowmap_oy"], L.COLUMN["rowmap_h"], L.STREAM["row_map"]
_ROW_MAP_HIGH = L.ROW_MAP >> L.WORD_BITS
_RSD, _RSM, _RSL, _RSN = L.COLUMN["rspike_density"], L.COLUMN["rspike_median"], L.COLUMN["rspike_log_std"], L.COLUMN["rspike_negative"]
_RSPIKE_WHERE, _RSPIKE_SIZE, _ROW_SPIKES_HIGH = L.STREAM["rspike_where"], L.STREAM["rspike_size"], L.ROW_SPIKES >> L.WORD_BITS
_HTD, _HOT_TILE_WHERE, _HOT_TILE_SIZE = L.COLUMN["hot_tile_density"], L.STREAM["hot_tile_where"], L.STREAM["hot_tile_size"]
_XTALK = L.STREAM["xtalk"]
_XT_DY = np.array([tap[0] for tap in L.XTALK_TAPS], dtype=np.int64)
_XT_DX = np.array([tap[1] for tap in L.XTALK_TAPS], dtype=np.int64)
_XT_PAD = L.XTALK_PAD
_ROW_SET = np.array(L.ROW_SET, dtype=np.int64)
_COL_SET = np.array(L.COLUMN_SET, dtype=np.int64)
_CHANNEL_AT = np.array(L.CHANNEL_AT, dtype=np.int64)
_NB_DY = np.array([n[0] for n in L.NEIGHBOURS], dtype=np.int64)
_NB_DX = np.array([n[1] for n in L.NEIGHBOURS], dtype=np.int64)
_SHC, _SHX, _SHY = L.COLUMN["share_c"], L.COLUMN["share_x"], L.COLUMN["share_y"]
_SHD1, _SHD2 = L.COLUMN["share_d1"], L.COLUMN["share_d2"]
_FMR, _FMOY, _FMOX, _FMH, _FMW = (L.COLUMN[c] for c in ("fmap_record", "fmap_oy", "fmap_ox", "fmap_h", "fmap_w"))
_FMGH, _FMGW, _FIXED_MAP_HIGH = L.COLUMN["fmap_gh"], L.COLUMN["fmap_gw"], L.FIXED_MAP >> L.WORD_BITS
_SHARE_DIAG_HIGH = L.CHARGE_SHARE_DIAG >> L.WORD_BITS


@njit(inline="always")
def _bilinear_at(y, x, h, w, gh, gw):
    """(y0, x0, y1, x1, fy, fx) of bilinear upsampling (align_corners=False, edge-clamped)."""
    sy = min(max((y + 0.5) * gh / h - 0.5, 0.0), gh - 1.0)
    sx = min(max((x + 0.5) * gw / w - 0.5, 0.0), gw - 1.0)
    y0, x0 = int(sy), int(sx)
    return y0, x0, min(y0 + 1, gh - 1), min(x0 + 1, gw - 1), sy - y0, sx - x0


@njit(inline="always")
def grid_power(g, e):
    """``g ** e`` of a gain ``g >= 0``, as exp(e log g) (the Triton kernel's form); ``g`` itself
    where ``e`` is 1, 1 where ``e`` is 0, 0 for a gain of 0 (a masked pixel) and ``e > 0``."""
    if e == 1.0:
        return g
    if e == 0.0:
        return 1.0
    return math.exp(e * math.log(g)) if g > 0.0 else 0.0


@njit(inline="always")
def shading_at(grids, record, y, x, h, w, gh, gw):
    """Bilinear upsampling of the ``gh x gw`` grid ``record`` of ``grids`` (padded records) at (y, x)."""
    y0, x0, y1, x1, fy, fx = _bilinear_at(y, x, h, w, gh, gw)
    top = grids[record, y0, x0] * (1.0 - fx) + grids[record, y0, x1] * fx
    bottom = grids[record, y1, x0] * (1.0 - fx) + grids[record, y1, x1] * fx
    return top * (1.0 - fy) + bottom * fy


@njit(inline="always")
def lowfreq_at(normal, key, b, y, x, h, w, gh, gw):
    """A per-frame standard-normal grid (gh x gw, counter (b * gh + i) * gw + j) at (y, x)."""
    y0, x0, y1, x1, fy, fx = _bilinear_at(y, x, h, w, gh, gw)
    base = b * gh
    z00 = symmetric(normal, draw(key, (base + y0) * gw + x0))
    z01 = symmetric(normal, draw(key, (base + y0) * gw + x1))
    z10 = symmetric(normal, draw(key, (base + y1) * gw + x0))
    z11 = symmetric(normal, draw(key, (base + y1) * gw + x1))
    return (z00 * (1.0 - fx) + z01 * fx) * (1.0 - fy) + (z10 * (1.0 - fx) + z11 * fx) * fy


@njit(inline="always")
def banding_at(key, v, b, line, f0, a0):
    """Banding (DN) on sensor line ``line`` (a row, or a column) of sample b: sum of
    a_j cos(2 pi f_j line + phi_j), f_j and a_j in columns ``f0 + j`` and ``a0 + j``, the
    phase phi_j = 2 pi U(0, 1) drawn per frame and tone (counter b * BAND_TONES + j)."""
    out = 0.0
    for j in range(_TONES):
        a = v[a0 + j]
        if a != 0.0:
            phase = 2.0 * math.pi * unit(draw(key, b * _TONES + j))
            out += a * math.cos(2.0 * math.pi * v[f0 + j] * line + phase)
    return out


@njit(inline="always")
def diagonal_banding_at(key, v, b, sensor, ry, rx):
    """Diagonal banding (DN) at raw pixel (ry, rx) of sample b: sum of
    a_j cos(2 pi (fx_j rx + fy_j ry) + phi_j), the phase drawn as ``banding_at``'s, plus
    f_j cos(2 pi (fx_j rx + fy_j ry) + psi_j), psi_j the sensor's (counter ``layout.FIXED_PHASE`` +
    sensor * TONES + j): the same in every frame."""
    out = 0.0
    for j in range(_TONES):
        a, f = v[_DBA0 + j], v[_DBF0 + j]
        if a != 0.0 or f != 0.0:
            arg = 2.0 * math.pi * (v[_DBX0 + j] * rx + v[_DBY0 + j] * ry)
            if a != 0.0:
                out += a * math.cos(arg + 2.0 * math.pi * unit(draw(key, b * _TONES + j)))
            if f != 0.0:
                out += f * math.cos(arg + 2.0 * math.pi * unit(draw(key, _FIXED_PHASE + sensor * _TONES + j)))
    return out


@njit(inline="always")
def drift_at(normal, key, key_phase, v, a0, first, b, t):
    """Line drift (DN) on sensor line ``t`` (a row for RowDrift, a column for ColDrift) of
    sample b: over octaves j, a_j (column ``a0 + j``) times the linear interpolation of
    standard normals on nodes every s = 2^(j + first) sensor lines (counter ((b * OCTAVES + j) << 24)
    + node), the grid shifted by a whole number of lines floor(s U(0, 1)) drawn per frame and
    octave (counter b * OCTAVES + j)."""
    out = 0.0
    for j in range(_OCT):
        a = v[a0 + j]
        if a != 0.0:
            s = 1 << (j + first)
            u = t + int(unit(draw(key_phase, b * _OCT + j)) * s)
            i = u // s
            f = (u - i * s) / s
            base = (b * _OCT + j) << 24
            out += a * (symmetric(normal, draw(key, base + i)) * (1.0 - f) + symmetric(normal, draw(key, base + i + 1)) * f)
    return out


@njit(inline="always")
def repeated_row_source(key, density, b, y, row_set, h):
    """The packed row whose whole chain packed row ``y`` of sample b reads out: while its sensor
    row 2y + row_set is a repeat in this frame (U < density, counter b * 2h + sensor row), the
    same colour's row above, back over at most REPEAT_CHAIN rows."""
    for _ in range(_CHAIN):
        if y < 1 or unit(draw(key, b * 2 * h + 2 * y + row_set)) >= density:
            break
        y -= 1
    return y


@njit(inline="always")
def crosstalk_at(normal, key, v, b, ry, rx, rh, rw):
    """Correlated read noise (DN) at raw pixel (ry, rx) of a raw frame rh x rw of sample b:
    sum over the taps (dy, dx) of XTALK_TAPS of h g(ry - dy, rx - dx), g one per-frame
    standard normal field (counter over the frame padded by XTALK_PAD on every side)."""
    out = 0.0
    base = b * (rh + 2 * _XT_PAD)
    for i in range(_XT_DY.shape[0]):
        h = v[_XT0 + i]
        if h != 0.0:
            out += h * symmetric(normal, draw(key, (base + ry - _XT_DY[i] + _XT_PAD) * (rw + 2 * _XT_PAD)
                                              + rx - _XT_DX[i] + _XT_PAD))
    return out


@njit(inline="always")
def defect_line_at(normal, key, line, density, median, log_std, negative):
    """Offset (DN) of sensor line ``line`` of a seeded defect-line pattern: 0, or
    +-median * exp(log_std * z) where the line's U(0, 1) falls below ``density``."""
    if unit(draw(key, 3 * line)) >= density:
        return 0.0
    size = median * math.exp(log_std * symmetric(normal, draw(key, 3 * line + 1)))
    return -size if unit(draw(key, 3 * line + 2)) < negative else size


@njit(inline="always")
def line_part(key, line, partial, to_end, cut_lo, cut_hi, pos, n):
    """1 where the element at sensor position ``pos`` of the ``n`` along sensor line ``line``
    lies in the line's defect, else 0: with probability ``partial`` the defect holds only from a
    break at U(cut_lo, cut_hi) x n to the line's end (with probability ``to_end``) or from its
    start to there; else the whole line."""
    if partial <= 0.0 or unit(draw(key, 3 * line)) >= partial:
        return 1.0
    cut = (cut_lo + (cut_hi - cut_lo) * unit(draw(key, 3 * line + 2))) * n
    along = pos + 0.5
    if unit(draw(key, 3 * line + 1)) < to_end:
        return 1.0 if along >= cut else 0.0
    return 1.0 if along < cut else 0.0


@njit(inline="always")
def dead_line_slot(key, line, density, partial, to_end, cut_lo, cut_hi, pos, n):
    """Level slot (0 .. DEAD_LEVELS - 1) of the element at sensor position ``pos`` of the ``n``
    along sensor line ``line`` where the line is dead there, else -1: the line is dead where its
    U(0, 1) falls below ``density``; with probability ``partial`` only from a break at
    U(cut_lo, cut_hi) x n to the line's end (with probability ``to_end``) or from its start to there."""
    if unit(draw(key, 5 * line)) >= density:
        return -1
    if unit(draw(key, 5 * line + 1)) < partial:
        along = pos + 0.5
        cut = (cut_lo + (cut_hi - cut_lo) * unit(draw(key, 5 * line + 3))) * n
        if (along < cut) if unit(draw(key, 5 * line + 2)) < to_end else (along >= cut):
            return -1
    return min(int(unit(draw(key, 5 * line + 4)) * _NDL), _NDL - 1)


@njit(inline="always")
def tap_at(line, v, first, lines):
    """Readout tap (0 .. TAP_EDGES) of sensor line ``line`` along one axis: the edges at or
    below it, stored as fractions of ``lines`` in ``v[first:first + TAP_EDGES]`` (2: none)."""
    tap = 0
    for i in range(_TPE):
        if line >= v[first + i] * lines:
            tap += 1
    return tap


@njit(inline="always")
def block_at(pos, v, first, size):
    """Read-noise map block (0 .. READ_MAP_BLOCKS - 1) of packed position ``pos`` of a frame of
    ``size``: the edges at or below it, stored as fractions of ``size`` in
    ``v[first:first + READ_MAP_BLOCKS - 1]`` (2: none)."""
    block = 0
    for i in range(_NB - 1):
        if pos >= v[first + i] * size:
            block += 1
    return block


@njit(inline="always")
def table_at(lut, row, z):
    """Row ``row`` of ``lut`` (values on a uniform grid of normal scores in [-Z_MAX, Z_MAX])
    at score ``z``, linear between grid points, the end values beyond."""
    n = lut.shape[1]
    t = min(max((z + Z_MAX) * ((n - 1) / (2.0 * Z_MAX)), 0.0), n - 1.0)
    i = min(int(t), n - 2)
    f = t - i
    return lut[row, i] * (1.0 - f) + lut[row, i + 1] * f


@njit(inline="always")
def clean_at(c32, c64, g):
    """Clean value ``g`` of the batch, float64: from ``c64`` when it holds the batch (a float64
    input), else from ``c32`` (one compiled kernel for both input dtypes)."""
    return c64[g] if c64.size else np.float64(c32[g])


@njit(inline="always")
def neighbour_at(c32, c64, n, b, ry, rx, h, w, scale_in, gain, dark, wx, wy, wd1, wd2):
    """(index, signal in DN, weight) of raw neighbour ``n`` (of ``NEIGHBOURS``) of raw pixel
    (ry, rx) of sample b: its clean value through this pixel's ``gain`` and ``dark`` signal;
    weight 0 outside the frame (``wx``, ``wy``: the sides'; ``wd1``, ``wd2``: the diagonals')."""
    ny, nx = ry + _NB_DY[n], rx + _NB_DX[n]
    if not (0 <= ny < 2 * h and 0 <= nx < 2 * w):
        return 0, 0.0, 0.0
    gn = ((b * 4 + _CHANNEL_AT[ny & 1, nx & 1]) * h + (ny >> 1)) * w + (nx >> 1)
    weight = wx if n < 2 else wy if n < 4 else wd1 if n < 6 else wd2
    return gn, clean_at(c32, c64, gn) * scale_in * gain + dark, weight


@njit(nogil=True, cache=True)
def _rows(c32, c64, o32, o64, values, flags, flags_high, keys, span, h, w, r0, r1, read_tables, read_index, normal, fine, coarse,
          grids, code_lut, read_lut):
    """Rows ``r0 .. r1`` of the (B * 4 * H) rows of a (B, 4, H, W) batch, flattened, from
    ``c64`` (float64) or, when that is empty, ``c32`` (float32) into ``o64`` or ``o32`` alike;
    returns the count of non-finite clean values met (their outputs are NaN)."""
    bad = 0
    stages, stages_high = flags, flags_high  # stage-flag words 0 and 1 (``layout.flag_words``)
    sig = np.empty(w)  # the row's signal, DN, through the stages
    photo = np.empty(w)  # ... before the pixel's gains
    pixel = np.empty(w)  # ... after them, before the dark signal
    col_frame, col_fixed, col_of = np.empty(w), np.empty(w), -1  # column noise of (sample, channel) col_of: b * 4 + c
    col_drift, col_drift_of = np.empty(w), -1  # column drift of (sample, channel) col_drift_of
    col_tap, col_tap_of = np.empty(w), -1  # column noise per tap of (sample, channel) col_tap_of
    rt_z = np.empty(_TAPS)  # row noise per tap: this row's offset in each column tap
    for r in range(r0, r1):
        b = r // (4 * h)
        c = (r // h) % 4
        y = r % h
        v = values[b]
        k = v[_K]
        scale_in = span / v[_RATIO]
        scale_out = v[_RATIO] / span
        row_set, col_set = _ROW_SET[c], _COL_SET[c]
        out0 = r * w  # where the row is written
        if stages_high & _ROW_REPEAT_HIGH:  # a repeated row: the whole chain of the row it repeats, from here on
            y = repeated_row_source(keys[_ROW_REPEAT], v[_RPD], b, y, row_set, h)
            r = (b * 4 + c) * h + y
        sensor = int(v[_SENSOR])  # fixed patterns of this sample's sensor instance: planes of their own
        line = 0.0  # offsets shared by the whole row
        if stages & L.ROW:
            z_row = symmetric(normal, draw(keys[_ROW], (b * 2 + row_set) * h + y))
            if stages & L.ROW_TAIL:  # heavy tails: Tukey's h transform, scaled back to unit variance
                z_row *= math.exp(0.5 * v[_RH] * z_row * z_row) * (1.0 - 2.0 * v[_RH]) ** 0.75
            line += v[_R] * z_row
        if stages_high & _ROW_MAP_HIGH:  # the row block's own row noise, per sensor row and frame
            rwh = int(v[_ROWMAP_H]) if v[_ROWMAP_H] > 0.0 else h
            line += (v[_ROWMAP_Y0 + min((y + int(v[_ROWMAP_OY])) * _NB // rwh, _NB - 1)]
                     * symmetric(normal, draw(keys[_ROW_MAP], (b * 2 + row_set) * h + y)))
        if stages_high & _ROW_SPIKES_HIGH:  # a row glitch of this frame: the whole sensor row offset
            q = b * 2 * h + 2 * y + row_set
            if unit(draw(keys[_RSPIKE_WHERE], 2 * q)) < v[_RSD]:
                size = v[_RSM] * math.exp(v[_RSL] * symmetric(normal, draw(keys[_RSPIKE_SIZE], q)))
                line += -size if unit(draw(keys[_RSPIKE_WHERE], 2 * q + 1)) < v[_RSN] else size
        if stages_high & _DARK_ROW_NOISE_HIGH:  # exposure row noise: the sensor row's offset of this frame
            line += v[_DRN] * symmetric(normal, draw(keys[_DARK_ROW_NOISE], (b * 2 + row_set) * h + y))
        if stages_high & _ROW_PAIR_HIGH:  # the row pair's shared offset of this frame: packed row y holds the pair
            line += v[_RPAIR] * symmetric(normal, draw(keys[_ROW_PAIR], b * h + y))
        if stages_high & _BLACK_RAMP_HIGH:  # this frame's black ramp down the sensor rows, about the frame's middle row
            line += v[_RAMP_ROW] * symmetric(normal, draw(keys[_BLACK_RAMP], 2 * b)) * (2 * y + row_set - (2 * h - 1) * 0.5)
        if stages_high & _BLACK_STEP_HIGH and 2 * y + row_set >= v[_BSTEP_AT] * 2 * h:  # this frame's black step, from its row on
            line += v[_BSTEP_DN]
        if stages & L.BIAS:
            line += v[_B0 + c]
        if stages & L.BLE:
            line += v[_BS] * symmetric(normal, draw(keys[_BLE], b * 5))
            line += v[_BC] * symmetric(normal, draw(keys[_BLE], b * 5 + 1 + c))
        if stages & L.DARK_OFFSET:
            line += v[_DOFF]
        if stages & L.BLACK_DRIFT:
            line += v[_DRIFT]
        if stages & L.BAND:
            line += banding_at(keys[_BAND], v, b, 2 * y + row_set, _BF0, _BA0)
        if stages & L.ROW_CHANNEL:
            line += v[_RC] * symmetric(normal, draw(keys[_ROW_CHANNEL], (b * 4 + c) * h + y))
        if stages & L.ROW_DRIFT:
            line += drift_at(normal, keys[_ROW_DRIFT], keys[_ROW_DRIFT_PHASE], v, _DR0, 1, b, 2 * y + row_set)
        if stages & L.ROW_FIX:
            line += v[_RF] * symmetric(normal, draw(keys[_ROW_PATTERN], (sensor * 2 + row_set) * h + y))
        row_defect = 0.0  # a defect row over a part: added along the row below
        if stages & L.LINES:
            row_defect = defect_line_at(normal, keys[_LINES_ROW], (sensor * 2 + row_set) * h + y, v[_LRD], v[_LM], v[_LLS], v[_LNEG])
            if v[_LPART] <= 0.0:
                line += row_defect
                row_defect = 0.0
        if stages & L.BANK_OFFSET:  # the sensor row's bank offset
            line += v[_BKR0 + (2 * y + row_set) % int(v[_BKRP])]
        lmrec, lmox, lmlw = 0, 0, 1
        if stages & L.LINE_MAP:  # measured line profiles: the row's offset here, the column's below (a larger input repeats them)
            lmrec, lmox, lmlw = int(v[_LMR]), int(v[_LMOX]), int(v[_LMLW])
            line += grids[lmrec, c, (y + int(v[_LMOY])) % int(v[_LMLH])]
        table = read_tables[read_index[b]]
        key_fine, key_rest, key_coarse = keys[_SHOT], keys[_SHOT_REST], keys[_SHOT_COARSE]
        record = int(v[_FR])
        # FPN shading: a window at (fpn_oy, fpn_ox) of a frame of fpn_h x fpn_w (0: this input)
        fy0 = y + v[_FOY]
        fh = v[_FH] if v[_FH] > 0.0 else float(h)
        fw = v[_FW] if v[_FW] > 0.0 else float(w)
        fox = v[_FOX]
        fgh, fgw = int(v[_FGH]), int(v[_FGW])
        # glow: a window at (glow_oy, glow_ox) of a frame of glow_h x glow_w (0: this input)
        gly0 = y + v[_GLOY]
        glh = v[_GLH] if v[_GLH] > 0.0 else float(h)
        glw = v[_GLW] if v[_GLW] > 0.0 else float(w)
        glox = v[_GLOX]
        glrec, glgh, glgw = int(v[_GLR]), int(v[_GLGH]), int(v[_GLGW])
        rmw, rmox, rm_row, rm_by, rm_rec = w, 0, 0.0, 0, -1
        if stages & L.READ_MAP:  # the row block's and channel's part of the read-noise map; the column block's and cell's below
            rmh = int(v[_RMH]) if v[_RMH] > 0.0 else h
            rmw = int(v[_RMW]) if v[_RMW] > 0.0 else w
            rmox = int(v[_RMOX])
            rm_by = block_at(y + int(v[_RMOY]), v, _RMYE0, rmh)
            rm_row = v[_RMC0 + c] ** 2 + v[_RMY0 + rm_by] ** 2
            rm_rec = int(v[_RMCR])
        tap_row, tap_ox, tap_cols = 0, 0, 2.0 * w
        if stages & L.TAP_BLACK:  # readout taps: this row's band of taps; the column's tap below
            tap_ox = int(v[_TPOX])
            tap_cols = 2.0 * (v[_TPW] if v[_TPW] > 0.0 else w)
            tap_row = tap_at(2 * (y + int(v[_TPOY])) + row_set, v, _TPR0, 2.0 * (v[_TPH] if v[_TPH] > 0.0 else h))
        tg_rec, tg_row, tg_ox, tg_cols = 0, 0, 0, 2.0 * w
        if stages & L.TAP_GAIN:  # readout taps' gains: this row's band of taps; the column's tap below
            tg_rec, tg_ox = int(v[_TGR]), int(v[_TGOX])
            tg_cols = 2.0 * (v[_TGW] if v[_TGW] > 0.0 else w)
            tg_row = tap_at(2 * (y + int(v[_TGOY])) + row_set, v, _TGR0, 2.0 * (v[_TGH] if v[_TGH] > 0.0 else h))
        lg_row = 1.0
        if stages & L.LINE_GAIN:  # the sensor row's gain if it is a gain defect; the column's below
            lg_row = max(1.0 + defect_line_at(normal, keys[_LGAIN_ROW], (sensor * 2 + row_set) * h + y, v[_LGRD], v[_LGM], v[_LGLS], v[_LGNEG]), 0.0)
        read_gain = v[_RG] if stages & L.FRAME_NOISE else 1.0  # this frame's factor on the base read noise
        row_gain = 1.0  # the sensor row's gain on the photo signal: its fixed part and this frame's
        if stages & L.ROW_GAIN:
            row_gain += (v[_RGF] * symmetric(normal, draw(keys[_ROWGAIN_PATTERN], (sensor * 2 + row_set) * h + y))
                         + v[_RGT] * symmetric(normal, draw(keys[_ROWGAIN_FRAME], (b * 2 + row_set) * h + y)))
        ggrec, ggy, ggpx, ggox = 0, 0, 1, 0
        if stages & L.GAIN_GRID:  # the grid row of this packed row: its period's phase
            ggrec, ggpx, ggox = int(v[_GGR]) + c, int(v[_GGPX]), int(v[_GGOX])
            ggy = (y + int(v[_GGOY])) % int(v[_GGPY])
        g0 = r * w
        p0 = ((sensor * 4 + c) * h + y) * w
        # stage by stage along the row (a stage's flag read once per row, not per element): each
        # element goes through the same operations in the same order as in one pass over it
        for x in range(w):
            g = g0 + x
            s = clean_at(c32, c64, g) * scale_in
            if not math.isfinite(s):
                bad += 1
            sig[x] = s
            photo[x] = s  # the photo signal before the pixel's gains (charge sharing takes its neighbours' through them)
        if stages & L.PRNU:
            for x in range(w):
                p = p0 + x
                s = sig[x]
                s *= 1.0 + v[_PRNU] * symmetric(normal, draw(keys[_PRNU_PATTERN], p))
                sig[x] = s
        if stages & L.GAIN_GRID:  # the measured periodic gain at this pixel, before the Poisson draw: its optical share
            for x in range(w):
                s = sig[x]
                s *= grid_power(grids[ggrec, ggy, (x + ggox) % ggpx], 1.0 - v[_GGCONV])
                sig[x] = s
        if stages_high & _MASKED_HIGH:  # masked lines: no light at the frame's edges (the dark signal stays)
            sy = 2 * y + row_set
            row_dark = sy < v[_MASK_T] or sy >= 2 * h - v[_MASK_B]
            for x in range(w):
                sx = 2 * x + col_set
                if row_dark or sx < v[_MASK_L] or sx >= 2 * w - v[_MASK_R]:
                    sig[x] = 0.0 * sig[x]  # NaN/Inf pass through
        if stages & (L.DARK_DRIFT | L.CHARGE_SHARE):  # ... and after them: the dark signal is what the stages below add
            for x in range(w):
                pixel[x] = sig[x]
        if stages & L.DARK_CURRENT:
            sr = v[_DSNU_ROW]  # the sensor row's log-normal factor of mean 1 (row DSNU)
            row_f = sr * symmetric(normal, draw(keys[_DSNU_ROW_PATTERN], (sensor * 2 + row_set) * h + y)) - 0.5 * sr * sr if sr > 0.0 else 0.0
            for x in range(w):
                p = p0 + x
                s = sig[x]
                sl = v[_DSNU_LOG]  # a log-normal rate map of mean 1
                sc = v[_DSNU_COL]  # ... times the sensor column's log-normal factor of mean 1
                col = sc * symmetric(normal, draw(keys[_DSNU_COL_PATTERN], (sensor * 2 + col_set) * w + x)) - 0.5 * sc * sc if sc > 0.0 else 0.0
                s += k * v[_DARK_E] * v[_DARK_C0 + c] * math.exp(sl * symmetric(normal, draw(keys[_DSNU_PATTERN], p)) - 0.5 * sl * sl + col + row_f)
                sig[x] = s
        if stages & L.GLOW:
            for x in range(w):
                s = sig[x]
                s += k * v[_GLS] * shading_at(grids, glrec, gly0, x + glox, glh, glw, glgh, glgw)
                sig[x] = s
        if stages & L.DARK_HOT:  # a hot pixel's dark electrons: the median this exposure times its log-normal factor
            for x in range(w):
                p = p0 + x
                s = sig[x]
                if unit(draw(keys[_DHOT_WHERE], p)) < v[_DHD]:
                    s += k * v[_DHE] * math.exp(v[_DHL] * symmetric(normal, draw(keys[_DHOT_SIZE], p)))
                sig[x] = s
        if stages_high & _DARK_CLUSTER_HIGH:  # hot clusters: the electrons of every patch seeded up to size - 1 sensor pixels above and left
            size = int(v[_CLS])
            sy0 = sensor * 2 * h
            for x in range(w):
                s = sig[x]
                sx = 2 * x + col_set
                for dy in range(size):
                    yy = 2 * y + row_set - dy
                    if yy < 0:
                        break
                    for dx in range(size):
                        xx = sx - dx
                        if xx < 0:
                            break
                        q = (sy0 + yy) * 2 * w + xx
                        if unit(draw(keys[_DCLUS_WHERE], q)) < v[_CLD]:
                            s += k * v[_CLE] * math.exp(v[_CLL] * symmetric(normal, draw(keys[_DCLUS_SIZE], q)))
                sig[x] = s
        if stages & L.DARK_RTS:  # a dark-current telegraph pixel's step of electrons, in the frames where it is high
            for x in range(w):
                g = g0 + x
                p = p0 + x
                s = sig[x]
                if unit(draw(keys[_DRTS_WHERE], p)) < v[_TDD] and unit(draw(keys[_DRTS_STATE], g)) < v[_TDH]:
                    s += k * v[_TDE] * math.exp(v[_TDL] * symmetric(normal, draw(keys[_DRTS_SIZE], p)))
                sig[x] = s
        if stages & L.DARK_COL:  # a leaky sensor column's dark electrons, keyed by the column
            for x in range(w):
                s = sig[x]
                q = (sensor * 2 + col_set) * w + x
                if unit(draw(keys[_DCOL_WHERE], q)) < v[_DCD]:
                    s += k * v[_DCE] * math.exp(v[_DCL] * symmetric(normal, draw(keys[_DCOL_SIZE], q)))
                sig[x] = s
        if stages & L.DARK_ROW:  # a leaky sensor row's dark electrons, keyed by the row
            for x in range(w):
                s = sig[x]
                q = (sensor * 2 + row_set) * h + y
                if unit(draw(keys[_DROW_WHERE], q)) < v[_DRD]:
                    s += k * v[_DRE] * math.exp(v[_DRL] * symmetric(normal, draw(keys[_DROW_SIZE], q)))
                sig[x] = s
        if stages & L.DARK_DRIFT:  # this frame's factor on every dark signal above
            for x in range(w):
                s_pixel = pixel[x]
                s = sig[x]
                s = s_pixel + v[_DDF] * (s - s_pixel)
                sig[x] = s
        if stages & (L.SHOT_POISSON | L.SHOT_GAUSS):
            for x in range(w):
                g = g0 + x
                p = p0 + x
                s_photo = photo[x]
                s_pixel = pixel[x]
                s = sig[x]
                share = (stages & L.CHARGE_SHARE) != 0 and math.isfinite(s)  # shot deviations mixed with the raw neighbours'
                around = 8 if stages_high & _SHARE_DIAG_HIGH else 4  # the sides, and the diagonals
                if share:
                    gain = s_pixel / s_photo if s_photo != 0.0 else 1.0
                    dark = s - s_pixel
                    ry, rx = 2 * y + row_set, 2 * x + col_set
                    mean = max(s, 0.0) if stages & L.SHOT_POISSON else s
                    shared = 0.0
                if stages & L.SHOT_POISSON:  # exact Poisson: tables and PTRS of rawaug.cpu.poisson, inlined (a call with the table tuples per element costs ~100 ns)
                    s_own = s
                    for n in range(1 + around if share else 1):  # this pixel, then (charge sharing) its raw neighbours
                        gn, sn, wn = g, s_own, v[_SHC]
                        if n > 0:
                            gn, sn, wn = neighbour_at(c32, c64, n - 1, b, ry, rx, h, w, scale_in, gain, dark, v[_SHX], v[_SHY],
                                                      v[_SHD1], v[_SHD2])
                        lam = sn / k
                        if not math.isfinite(lam) or (share and wn == 0.0):
                            continue  # NaN/Inf pass through (counted above); a neighbour off the frame adds nothing
                        if not lam > 0.0:
                            count = 0.0
                        elif lam < COARSE_MAX:
                            count = 0
                            if lam >= TABLE_MAX:
                                j = int(lam * (1.0 / TABLE_MAX))
                                count = _table_count(draw(key_coarse, gn), j, coarse)
                                lam -= j * TABLE_MAX  # exact
                            j = int(lam * (1.0 / GRID_STEP))
                            z = draw(key_fine, gn)
                            count += _table_count(z, j, fine) + _small_poisson(lam - j * GRID_STEP, z & SPARE_BITS, key_rest, gn)
                        else:
                            count = _ptrs(lam, draw(key_rest, gn))
                        if share:
                            shared += wn * (count * k - max(sn, 0.0))
                        else:
                            s = count * k
                    if share:
                        s = mean + shared
                elif stages & L.SHOT_GAUSS:
                    if share:
                        shared = v[_SHC] * math.sqrt(k * max(s, 0.0)) * symmetric(normal, draw(keys[_SHOT], g))
                        for n in range(around):
                            gn, sn, wn = neighbour_at(c32, c64, n, b, ry, rx, h, w, scale_in, gain, dark, v[_SHX], v[_SHY],
                                                      v[_SHD1], v[_SHD2])
                            if wn != 0.0 and math.isfinite(sn):
                                shared += wn * math.sqrt(k * max(sn, 0.0)) * symmetric(normal, draw(keys[_SHOT], gn))
                        s = mean + shared
                    else:
                        s += math.sqrt(k * max(s, 0.0)) * symmetric(normal, draw(keys[_SHOT], g))
                sig[x] = s
        if stages_high & _FULL_WELL_HIGH:  # a pixel holds at most its full well: K x its electrons (keyed by the sensor's pixel)
            for x in range(w):
                s = sig[x]
                if math.isfinite(s):
                    s = min(s, k * v[_WELL] * (1.0 + v[_WELL_SPREAD] * symmetric(normal, draw(keys[_WELL_PATTERN], p0 + x))))
                sig[x] = s
        if stages & L.TRAP:  # traps of q DN (K q electrons) take q (1 - exp(-s / q)) of a charge s > 0
            trap = v[_TRAP]
            if trap > 0.0:
                for x in range(w):
                    s = sig[x]
                    if s > 0.0:
                        s -= trap * (1.0 - math.exp(-s / trap))
                    sig[x] = s
        if stages & L.NONLIN:  # the photo signal compressed: s (1 - c s) above 0 DN
            for x in range(w):
                s = sig[x]
                s -= v[_NL + c] * s * max(s, 0.0)
                sig[x] = s
        if stages & L.FRAME_GAIN:  # this frame's gain on the photo signal and its shot noise
            for x in range(w):
                s = sig[x]
                s *= v[_FG]
                sig[x] = s
        if stages & L.GAIN_GRID and v[_GGCONV] > 0.0:  # ... and its conversion share, on the photo signal and its shot noise
            for x in range(w):
                s = sig[x]
                s *= grid_power(grids[ggrec, ggy, (x + ggox) % ggpx], v[_GGCONV])
                sig[x] = s
        if stages & L.COL_GAIN:  # the sensor column's amplifier gain on the photo signal and its shot noise
            for x in range(w):
                s = sig[x]
                s *= (1.0 + v[_CGS] * symmetric(normal, draw(keys[_COLGAIN_PATTERN], (sensor * 2 + col_set) * w + x))
                      + v[_CGT] * symmetric(normal, draw(keys[_COLGAIN_FRAME], (b * 2 + col_set) * w + x)))
                sig[x] = s
        if stages & L.ROW_GAIN:  # the sensor row's gain on the photo signal and its shot noise
            for x in range(w):
                s = sig[x]
                s *= row_gain
                sig[x] = s
        if stages & L.PIXEL_GAIN:  # a gain defect pixel's gain on its photo signal (keyed by the sensor's pixel)
            for x in range(w):
                s = sig[x]
                s *= max(1.0 + defect_line_at(normal, keys[_PGAIN], p0 + x, v[_PGD], v[_PGM], v[_PGL], v[_PGN]), 0.0)
                sig[x] = s
        if stages & L.GAIN_NOISE:  # the pixel's gain this frame on its signal: a relative normal draw, new at every pixel and frame
            for x in range(w):
                s = sig[x]
                s *= 1.0 + v[_GNS] * symmetric(normal, draw(keys[_GAIN_NOISE], g0 + x))
                sig[x] = s
        if stages & L.FPN:
            for x in range(w):
                p = p0 + x
                s = sig[x]
                s += v[_FS] * symmetric(normal, draw(keys[_FPN_PATTERN], p)) + shading_at(grids, record, fy0, x + fox, fh, fw, fgh, fgw)
                sig[x] = s
        if stages_high & _FIXED_MAP_HIGH:  # the measured fixed map: a window (fmap_oy, fmap_ox) of fmap_h x fmap_w (0: this input)
            mrec, mgh, mgw = int(v[_FMR]), int(v[_FMGH]), int(v[_FMGW])
            mh = v[_FMH] if v[_FMH] > 0.0 else float(h)
            mw = v[_FMW] if v[_FMW] > 0.0 else float(w)
            for x in range(w):
                s = sig[x]
                s += shading_at(grids, mrec, y + v[_FMOY], x + v[_FMOX], mh, mw, mgh, mgw)
                sig[x] = s
        if stages & L.HOT:
            for x in range(w):
                p = p0 + x
                s = sig[x]
                if unit(draw(keys[_HOT_WHERE], p)) < v[_HD]:
                    s += v[_HM] * math.exp(v[_HL] * symmetric(normal, draw(keys[_HOT_SIZE], p)))
                if v[_HTD] > 0.0:  # a hot tile: the four pixels of a 2x2 tile (a shared readout's defect) alike
                    pt = (sensor * h + y) * w + x
                    if unit(draw(keys[_HOT_TILE_WHERE], pt)) < v[_HTD]:
                        s += v[_HM] * math.exp(v[_HL] * symmetric(normal, draw(keys[_HOT_TILE_SIZE], pt)))
                sig[x] = s
        if stages & L.RTS:  # a telegraph pixel's step, in the frames where it is high
            for x in range(w):
                g = g0 + x
                p = p0 + x
                s = sig[x]
                if unit(draw(keys[_RTS_WHERE], p)) < v[_RTD] and unit(draw(keys[_RTS_STATE], g)) < v[_RTH]:
                    s += v[_RTM] * math.exp(v[_RTL] * symmetric(normal, draw(keys[_RTS_SIZE], p)))
                sig[x] = s
        if stages & L.NOISY:  # a noisy pixel's own temporal noise, new in every frame
            for x in range(w):
                g = g0 + x
                p = p0 + x
                s = sig[x]
                if unit(draw(keys[_NOISY_WHERE], p)) < v[_NZD]:
                    s += v[_NZM] * math.exp(v[_NZL] * symmetric(normal, draw(keys[_NOISY_SIZE], p))) * symmetric(normal, draw(keys[_NOISY_READ], g))
                sig[x] = s
        if stages & L.NOISY_COL:  # a noisy sensor column's extra temporal noise, new at every pixel and frame
            for x in range(w):
                g = g0 + x
                s = sig[x]
                q = (sensor * 2 + col_set) * w + x
                if unit(draw(keys[_NCOL_WHERE], q)) < v[_NCD]:
                    s += v[_NCM] * math.exp(v[_NCL] * symmetric(normal, draw(keys[_NCOL_SIZE], q))) * symmetric(normal, draw(keys[_NCOL_READ], g))
                sig[x] = s
        if stages_high & _BANK_NOISE_HIGH:  # a readout bank's extra white noise: its bank's std, new at every pixel and frame
            bank_p = int(v[_BNCP])
            for x in range(w):
                g = g0 + x
                s = sig[x]
                s += v[_BNC0 + (2 * x + col_set) % bank_p] * symmetric(normal, draw(keys[_BANK_NOISE], g))
                sig[x] = s
        if stages_high & _ROW_BURST_HIGH:  # a burst row of this frame: extra white noise at every pixel of the sensor row
            if unit(draw(keys[_BURST_ROW], b * 2 * h + 2 * y + row_set)) < v[_BRD]:
                for x in range(w):
                    sig[x] += v[_BRS] * symmetric(normal, draw(keys[_BURST_NOISE], g0 + x))
        if stages_high & _COL_BURST_HIGH:  # a burst column of this frame: extra white noise at every pixel of the sensor column
            for x in range(w):
                if unit(draw(keys[_BURST_COL], b * 2 * w + 2 * x + col_set)) < v[_CBD]:
                    sig[x] += v[_CBS] * symmetric(normal, draw(keys[_BURST_COL_NOISE], g0 + x))
        if stages & L.DARK_NOISE:  # exposure noise: white, new at every pixel and frame
            for x in range(w):
                sig[x] += v[_DNS] * symmetric(normal, draw(keys[_DARK_NOISE], g0 + x))
        if stages & (L.READ_TABLE | L.READ_TUKEY | L.READ_GAUSS):
            for x in range(w):
                g = g0 + x
                p = p0 + x
                s = sig[x]
                if stages & L.READ_TABLE:  # measured quantiles on a grid of normal scores, linear between
                    s += read_gain * v[_RQ_SCALE] * table_at(read_lut, int(v[_RQ_REC]) * 4 + c, symmetric(normal, draw(keys[_READ], g)))
                elif stages & L.READ_TUKEY:
                    s += read_gain * v[_TL] * symmetric(table, draw(keys[_READ], g))
                elif stages & L.READ_GAUSS:
                    s += read_gain * v[_G] * symmetric(normal, draw(keys[_READ], g))
                sig[x] = s
        if stages & L.XTALK:
            for x in range(w):
                s = sig[x]
                s += crosstalk_at(normal, keys[_XTALK], v, b, 2 * y + row_set, 2 * x + col_set, 2 * h, 2 * w)
                sig[x] = s
        if stages & L.SHARED:  # one value per frame and packed position: the tile's four pixels
            for x in range(w):
                s = sig[x]
                s += v[_SH] * symmetric(normal, draw(keys[_SHARED], (b * h + y) * w + x))
                sig[x] = s
        if stages & L.READ_MAP:
            for x in range(w):
                g = g0 + x
                s = sig[x]
                bx = block_at(x + rmox, v, _RMXE0, rmw)
                var = rm_row + v[_RMX0 + bx] ** 2 + (grids[rm_rec, rm_by, bx] if rm_rec >= 0 else 0.0)
                s += math.sqrt(var) * symmetric(normal, draw(keys[_READ_MAP], g))
                sig[x] = s
        if stages & L.SPIKES:  # a single-frame event at this pixel of this frame
            for x in range(w):
                g = g0 + x
                s = sig[x]
                u = unit(draw(keys[_SPIKE_WHERE], g))
                if u < v[_SPD]:  # the lowest share ``negative`` of the events' uniforms: a dark event
                    size = v[_SPM] * math.exp(v[_SPL] * symmetric(normal, draw(keys[_SPIKE_SIZE], g)))
                    s += -size if u < v[_SPD] * v[_SPN] else size
                sig[x] = s
        if stages & L.COL_RTS:  # a telegraph column's step, in the frames where it is high
            for x in range(w):
                s = sig[x]
                q = (sensor * 2 + col_set) * w + x
                if unit(draw(keys[_CRTS_WHERE], q)) < v[_CRD] and unit(draw(keys[_CRTS_STATE], (b * 2 + col_set) * w + x)) < v[_CRH]:
                    s += v[_CRM] * math.exp(v[_CRL] * symmetric(normal, draw(keys[_CRTS_SIZE], q)))
                sig[x] = s
        if stages & L.ROW_RTS:  # a telegraph row's step, in the frames where it is high
            for x in range(w):
                s = sig[x]
                q = (sensor * 2 + row_set) * h + y
                if unit(draw(keys[_RRTS_WHERE], q)) < v[_RRD] and unit(draw(keys[_RRTS_STATE], (b * 2 + row_set) * h + y)) < v[_RRH]:
                    s += v[_RRM] * math.exp(v[_RRL] * symmetric(normal, draw(keys[_RRTS_SIZE], q)))
                sig[x] = s
        if stages & L.COL:
            if col_of != r // h:  # a column's offsets are the same in every row of a channel: drawn once for them
                col_of = r // h
                rho = v[_CRHO]
                for x in range(w):
                    if rho > 0.0:  # a sequence's frames: an AR(1) over the frames 0 .. b of the batch
                        z = rho**b * symmetric(normal, draw(keys[_COL], col_set * w + x))
                        for m in range(1, b + 1):
                            z += math.sqrt(1.0 - rho * rho) * rho ** (b - m) * symmetric(normal, draw(keys[_COL], (m * 2 + col_set) * w + x))
                        col_frame[x] = v[_CS] * z
                    else:
                        col_frame[x] = v[_CS] * symmetric(normal, draw(keys[_COL], (b * 2 + col_set) * w + x))
                    col_fixed[x] = v[_CF] * symmetric(normal, draw(keys[_COL_PATTERN], (sensor * 2 + col_set) * w + x))
            for x in range(w):
                s = sig[x]
                s += col_frame[x]
                s += col_fixed[x]
                sig[x] = s
        if stages_high & _COL_TAP_HIGH:  # column noise of the column's tap: the sensor column's offset of this frame
            if col_tap_of != r // h:  # the same in every row of a channel: drawn once for them
                col_tap_of = r // h
                ct_cols = 2.0 * (v[_CTW] if v[_CTW] > 0.0 else w)
                for x in range(w):
                    tap = tap_at(2 * (x + int(v[_CTOX])) + col_set, v, _CTC0, ct_cols)
                    col_tap[x] = v[_CTS0 + tap] * symmetric(normal, draw(keys[_COL_TAP], (b * 2 + col_set) * w + x))
            for x in range(w):
                sig[x] += col_tap[x]
        if stages_high & _COL_GROUP_HIGH:  # a column group's offset of this frame: groups of width sensor columns from start
            width = max(int(v[_CGRW]), 1)
            shift = width - int(v[_CGR0])
            for x in range(w):
                sig[x] += v[_CGRS] * symmetric(normal, draw(keys[_COL_GROUP], b * 2 * w + (2 * x + col_set + shift) // width))
        if stages_high & _COL_DRIFT_HIGH:  # column drift: octaves of interpolated per-frame column offsets
            if col_drift_of != r // h:  # the same in every row of a channel: made once for them
                col_drift_of = r // h
                for x in range(w):
                    col_drift[x] = drift_at(normal, keys[_COL_DRIFT], keys[_COL_DRIFT_PHASE], v, _CDR0, 0, b, 2 * x + col_set)
            for x in range(w):
                s = sig[x]
                s += col_drift[x]
                sig[x] = s
        if stages & L.COL_BAND:  # tones along the sensor columns, a phase per frame and tone
            for x in range(w):
                s = sig[x]
                s += banding_at(keys[_COL_BAND], v, b, 2 * x + col_set, _CBF0, _CBA0)
                sig[x] = s
        if stages & L.DIAG_BAND:  # tones along both axes, a phase per frame and tone, and the sensor's
            for x in range(w):
                s = sig[x]
                s += diagonal_banding_at(keys[_DIAG_BAND], v, b, sensor, 2 * y + row_set, 2 * x + col_set)
                sig[x] = s
        if stages & L.LINES:
            for x in range(w):
                s = sig[x]
                cline = (sensor * 2 + col_set) * w + x
                off = defect_line_at(normal, keys[_LINES_COL], cline, v[_LCD], v[_LM], v[_LLS], v[_LNEG])
                if off != 0.0 and v[_LPART] > 0.0:
                    off *= line_part(keys[_LINES_COL_CUT], cline, v[_LPART], v[_LEND], v[_LCLO], v[_LCHI], 2 * y + row_set, 2 * h)
                s += off
                sig[x] = s
        if stages & L.LINE_MAP:
            for x in range(w):
                s = sig[x]
                s += grids[lmrec, 4 + c, (x + lmox) % lmlw]
                sig[x] = s
        if stages & L.BANK_OFFSET:  # the sensor column's bank offset
            bank_p = int(v[_BKCP])
            for x in range(w):
                s = sig[x]
                s += v[_BKC0 + (2 * x + col_set) % bank_p]
                sig[x] = s
        if stages & L.QUANT:
            for x in range(w):
                g = g0 + x
                s = sig[x]
                s += (unit(draw(keys[_QUANT], g)) - 0.5) * v[_Q]
                sig[x] = s
        if stages & L.LOW_FREQ:
            for x in range(w):
                s = sig[x]
                s += v[_LF] * lowfreq_at(normal, keys[_LOWFREQ], b, y, x, h, w, int(v[_LF_GH]), int(v[_LF_GW]))
                sig[x] = s
        if stages & L.FIXED_FIELD:  # the sensor's measured fixed field: its normal grid (counter by sensor), bilinear
            for x in range(w):
                s = sig[x]
                s += v[_FF] * lowfreq_at(normal, keys[_FFIELD], sensor, y, x, h, w, int(v[_FF_GH]), int(v[_FF_GW]))
                sig[x] = s
        if stages & L.LINE_GAIN:  # a gain defect line's gain on the pixel's signal and noise, its row's and its column's
            for x in range(w):
                s = sig[x]
                s *= lg_row * max(1.0 + defect_line_at(normal, keys[_LGAIN_COL], (sensor * 2 + col_set) * w + x, v[_LGCD], v[_LGM], v[_LGLS], v[_LGNEG]), 0.0)
                sig[x] = s
        if stages & L.TAP_GAIN:  # the readout tap's gain on the pixel's signal and noise (not the rows' and black levels' offsets)
            for x in range(w):
                s = sig[x]
                s *= grids[tg_rec, tg_row, tap_at(2 * (x + tg_ox) + col_set, v, _TGC0, tg_cols)]
                sig[x] = s
        if row_defect != 0.0:  # the row's offsets, its defect over a part where it is one
            rline = (sensor * 2 + row_set) * h + y
            for x in range(w):
                sig[x] += line + row_defect * line_part(keys[_LINES_ROW_CUT], rline, v[_LPART], v[_LEND], v[_LCLO], v[_LCHI],
                                                        2 * x + col_set, 2 * w)
        else:
            for x in range(w):
                sig[x] += line
        if stages_high & _BLACK_RAMP_HIGH:  # this frame's black ramp across the sensor columns, about the middle column
            slope = v[_RAMP_COL] * symmetric(normal, draw(keys[_BLACK_RAMP], 2 * b + 1))
            for x in range(w):
                sig[x] += slope * (2 * x + col_set - (2 * w - 1) * 0.5)
        if stages_high & _ROW_TAP_HIGH:  # row noise of the pixel's column tap: the sensor row's offset of this frame there
            rt_line = ((b * 2 + row_set) * h + y) * _TAPS
            for t in range(_TAPS):
                rt_z[t] = v[_RTS] * symmetric(normal, draw(keys[_ROW_TAP], rt_line + t))
            rt_cols = 2.0 * (v[_RTW] if v[_RTW] > 0.0 else w)
            for x in range(w):
                sig[x] += rt_z[tap_at(2 * (x + int(v[_RTOX])) + col_set, v, _RTC0, rt_cols)]
        if stages & L.TAP_BLACK:  # this frame's offset of the pixel's tap
            for x in range(w):
                s = sig[x]
                tap = tap_row * _TAPS + tap_at(2 * (x + tap_ox) + col_set, v, _TPC0, tap_cols)
                s += v[_TPS] * symmetric(normal, draw(keys[_TAP], b * _TAPS * _TAPS + tap))
                sig[x] = s
        if stages & L.ADC_DNL:
            for x in range(w):
                g = g0 + x
                p = p0 + x
                s = sig[x]
                if stages & L.ADC_DNL and math.isfinite(s):  # the code whose decision levels hold s
                    code = float(math.floor(s + 0.5))
                    period = int(v[_DNL_P])
                    j = int(code) % period
                    if s < code - 0.5 + v[_DNL_E0 + j]:
                        code -= 1.0
                    elif s >= code + 0.5 + v[_DNL_E0 + (j + 1) % period]:
                        code += 1.0
                    s = code
                sig[x] = s
        if stages & L.CODE_MAP:
            rec = int(v[_CM_REC0 + c])  # the channel's map (-1: none, rounded only)
            cm_lo = code_lut[rec, 3, 0] if rec >= 0 else 0.0
            cm_n = int(code_lut[rec, 3, 1]) if rec >= 0 else 0
            period = int(code_lut[rec, 3, 2]) if rec >= 0 else 0
            comb_from = code_lut[rec, 3, 3] if rec >= 0 else 0.0
            comb_to = code_lut[rec, 3, 4] if rec >= 0 else 0.0
            for x in range(w):
                s = sig[x]
                code = math.floor(s + 0.5)
                i = int(code - cm_lo)
                if 0 <= i < cm_n:  # the code below the split, or the one above
                    s = code_lut[rec, 0, i] if s - code < code_lut[rec, 2, i] else code_lut[rec, 1, i]
                elif period > 0 and comb_from <= code <= comb_to:  # a periodic comb goes on beyond the measured range: the first period's shifts
                    j = i % period
                    part = 0 if s - code < code_lut[rec, 2, j] else 1
                    s = code + code_lut[rec, part, j] - (cm_lo + j)
                else:
                    s = code
                sig[x] = s
        if stages & L.DEAD:  # a dead pixel reads its stuck level, whatever came before; so does a dead line's part
            for x in range(w):
                p = p0 + x
                s = sig[x]
                if unit(draw(keys[_DEAD_WHERE], p)) < v[_DD]:
                    s = v[_DL0 + min(int(unit(draw(keys[_DEAD_LEVEL], p)) * _NDL), _NDL - 1)]
                else:
                    slot = -1
                    if v[_DCOL] > 0.0:
                        slot = dead_line_slot(keys[_DEAD_COL], (sensor * 2 + col_set) * w + x, v[_DCOL], v[_DPART], v[_DEND],
                                              v[_DCLO], v[_DCHI], 2 * y + row_set, 2 * h)
                    if slot < 0 and v[_DROW] > 0.0:
                        slot = dead_line_slot(keys[_DEAD_ROW], (sensor * 2 + row_set) * h + y, v[_DROW], v[_DPART], v[_DEND],
                                              v[_DCLO], v[_DCHI], 2 * x + col_set, 2 * w)
                    if slot >= 0:
                        s = v[_DL0 + slot]
                sig[x] = s
        if stages & L.STUCK_BIT:  # the raw code the converter writes, its stuck bits cleared or set
            zero = v[_SBZ0 + c]
            low, high = int(v[_SBLO]), int(v[_SBHI])
            for x in range(w):
                s = sig[x]
                if math.isfinite(s):
                    code = int(math.floor(s + 0.5) + zero)
                    s = float((code - (code & low)) | high) - zero
                sig[x] = s
        if stages & L.CLIP:
            for x in range(w):
                s = sig[x]
                s = max(s, v[_CL])
                sig[x] = s
        if stages & L.CLIP_WHITE:
            for x in range(w):
                s = sig[x]
                s = min(s, span)
                sig[x] = s
        if o64.size:
            for x in range(w):
                o64[out0 + x] = sig[x] * scale_out
        else:
            for x in range(w):
                o32[out0 + x] = sig[x] * scale_out
    return bad


def synthesize(clean, out, values, flags, flags_high, keys, span, read_tables, read_index, normal, fine, coarse, grids, code_lut,
               read_lut, threads=1):
    """Run the fused chain over a (B, 4, H, W) NumPy batch into ``out`` (may be ``clean``);
    returns the count of non-finite clean values. ``clean`` and ``out`` are float32 or float64
    (computed in float64 either way; one compiled kernel takes both: 20 s a compile)."""
    from .parallel import run_ranges

    b, _, h, w = clean.shape
    c32, c64 = _as_float32_or_64(clean.reshape(-1), "clean")
    o32, o64 = _as_float32_or_64(out.reshape(-1), "out")
    keys = np.asarray(keys, dtype=np.uint64)
    return run_ranges(lambda r0, r1: _rows(c32, c64, o32, o64, values, np.int64(flags), np.int64(flags_high), keys, float(span), h, w, r0, r1,
                                           read_tables, read_index, normal, fine, coarse, grids, code_lut, read_lut),
                      b * 4 * h, w, threads)


_EMPTY32, _EMPTY64 = np.empty(0, np.float32), np.empty(0, np.float64)


def _as_float32_or_64(flat, name):
    """(float32 view, float64 view) of a flat array, the other one empty."""
    if flat.dtype == np.float64:
        return _EMPTY32, flat
    if flat.dtype == np.float32:
        return flat, _EMPTY64
    raise TypeError(f"{name} is {flat.dtype}; expected float32 or float64")
