"""What the fused kernels read: stage flags, parameter columns and stream slots.

Plain constants, imported by the effects (which fill them), the CPU and Triton kernels
(which read them) and the engine (which packs them). One column per scalar a stage needs
per sample; one stream slot per random stream a stage draws from.
"""
from __future__ import annotations

# Stage flags, in physical order (photons -> electrons -> voltage -> DN).
PRNU = 1 << 0  # pixel gain map on the photo signal
SHOT_POISSON = 1 << 1  # P*
SHOT_GAUSS = 1 << 2  # P
FPN = 1 << 3  # dark shading + white fixed pattern
HOT = 1 << 4  # hot pixels
READ_TUKEY = 1 << 5  # G*
READ_GAUSS = 1 << 6  # G
ROW = 1 << 7  # R
COL = 1 << 8  # column noise
QUANT = 1 << 9  # U
BIAS = 1 << 10  # C
BLE = 1 << 11  # frame black-level error
CLIP = 1 << 12  # black clipping
CLIP_WHITE = 1 << 13  # clipping at white
DARK_CURRENT = 1 << 14  # dark electrons (and their non-uniformity), before shot noise
LOW_FREQ = 1 << 15  # measured fallback: per-frame low-frequency field (bilinear random grid)
CODE_MAP = 1 << 16  # measured fallback: output codes mapped to the codes the camera uses
READ_TABLE = 1 << 17  # measured fallback: read noise from a measured quantile table (in place of G* / G)
LINES = 1 << 18  # defect lines: sparse sensor rows and columns with a large fixed offset
GLOW = 1 << 19  # amplifier glow: a smooth dark-current map (electrons per second), before shot noise
NONLIN = 1 << 20  # gain non-linearity: the photo signal compressed after shot noise, before read noise
XTALK = 1 << 21  # correlated read noise: one white field per frame through a small readout kernel (XTALK_TAPS)
BAND = 1 << 22  # periodic banding: tones along the sensor rows, a random phase in every frame
ROW_FIX = 1 << 23  # fixed row pattern: one offset per sensor row, the same in every frame
ROW_CHANNEL = 1 << 24  # row noise of each channel's own: one offset per packed row and frame
READ_MAP = 1 << 25  # read-noise non-uniformity: extra white read noise per channel, row block and column block
SHARED = 1 << 26  # shared-pixel readout: read noise shared by the four pixels of a Bayer tile
RTS = 1 << 27  # random telegraph noise: sparse pixels with a step, in the high state in some frames
DEAD = 1 << 28  # dead (stuck) pixels: sparse pixels whose output is a fixed level, whatever the signal and noise
ROW_DRIFT = 1 << 29  # row noise with a low-frequency spectrum: octaves of interpolated random row offsets per frame
COL_BAND = 1 << 30  # column banding: tones along the sensor columns, a random phase in every frame
DARK_HOT = 1 << 31  # hot pixels of dark current: sparse pixels with a high dark-current rate, before shot noise
COL_GAIN = 1 << 32  # column gain non-uniformity: each sensor column's amplifier multiplies the photo signal by its own gain
DIAG_BAND = 1 << 33  # diagonal banding: tones along both sensor axes (a serial readout's interference), a phase per frame and a fixed one
DARK_COL = 1 << 34  # leaky columns: sparse sensor columns with a high dark-current rate, before shot noise
DARK_OFFSET = 1 << 35  # black level moving with exposure time, without shot noise (clamp sag, amplifier warm-up)
SPIKES = 1 << 36  # impulsive noise: single-frame events at random pixels (cosmic rays, charge bursts), after read noise
COL_RTS = 1 << 37  # column telegraph noise: sparse sensor columns with two offsets, a state per frame
FRAME_NOISE = 1 << 38  # frame-to-frame read-noise level: the base read noise of a frame times its own factor
FRAME_GAIN = 1 << 39  # frame-to-frame gain: the photo signal of a frame times its own factor, after shot noise
LINE_MAP = 1 << 40  # measured fallback: fixed row and column offset profiles of the measured frame
ROW_GAIN = 1 << 41  # row gain: each sensor row's gain on the photo signal, fixed and new in every frame
GAIN_GRID = 1 << 42  # measured fallback: a periodic grid of pixel gains on the photo signal (phase-detection pixels)
BLACK_DRIFT = 1 << 43  # black level drifting over a sequence of frames (AR(1) across consecutive frames), all channels
CHARGE_SHARE = 1 << 44  # charge sharing: each shot deviation mixed with its four raw neighbours' (diffusion, inter-pixel capacitance)
DARK_ROW = 1 << 45  # leaky rows: sparse sensor rows with a high dark-current rate, before shot noise
NOISY = 1 << 46  # noisy pixels: sparse pixels with extra Gaussian temporal noise, new in every frame
DARK_RTS = 1 << 47  # dark-current telegraph: sparse pixels whose dark-current rate takes two states, a state per frame, before shot noise
NOISY_COL = 1 << 48  # noisy columns: sparse sensor columns whose pixels read with extra Gaussian temporal noise, new at every pixel and frame
ROW_RTS = 1 << 49  # row telegraph noise: sparse sensor rows with two offsets, a state per frame
TAP_BLACK = 1 << 50  # readout taps: a grid of regions, each with a black-level offset of its own in every frame
TAP_GAIN = 1 << 51  # readout taps: a grid of regions, each with a gain of its own on the photo signal
LINE_GAIN = 1 << 52  # gain defect lines: sparse sensor rows and columns with a gain far off, on the pixel's signal and noise
ADC_DNL = 1 << 54  # ADC differential non-linearity: the codes' decision levels off their places, periodic in the code
DARK_DRIFT = 1 << 53  # dark-signal drift: a factor per frame on every dark signal (the sensor's temperature), before shot noise
DARK_NOISE = 1 << 55  # exposure noise: white Gaussian temporal noise whose variance grows with the exposure time, with the read noise
TRAP = 1 << 56  # charge trapping: the first electrons of a pixel's charge lost, after shot noise, before the gain non-linearity
FIXED_FIELD = 1 << 60  # measured fallback: a fixed smooth field, a sensor's bilinear normal grid at a measured cell size
ROW_TAIL = 1 << 59  # heavy-tailed row noise: R's standard normal draw through Tukey's h transform
PIXEL_GAIN = 1 << 58  # gain defect pixels: sparse pixels whose gain on the photo signal is far off, fixed
GAIN_NOISE = 1 << 57  # pixel gain noise: each pixel's gain on its signal moves by a relative normal draw, new at every pixel and frame
STUCK_BIT = 1 << 61  # stuck ADC bits: the raw code's bits of a mask read 0, of another 1
BANK_OFFSET = 1 << 62  # readout bank offsets: fixed offsets repeating with the interleaved column / row banks' period
# The kernels take the flags as words of WORD_BITS bits (each a non-negative int64): the stages
# above are word 0, those below word 1 (``flag_words``).
WORD_BITS = 63
COL_DRIFT = 1 << 63  # column drift: column noise with a low-frequency spectrum, octaves of interpolated random column offsets per frame
ROW_REPEAT = 1 << 64  # repeated rows: sensor rows that read out as the same colour's row above (a line buffer read twice), new in every frame
REPEAT_CHAIN = 4  # repeated rows: the longest run of rows one repeat reaches back over
BANK_NOISE = 1 << 65  # readout bank noise: extra white temporal noise of its own per interleaved column bank, new at every pixel and frame
DARK_CLUSTER = 1 << 66  # clusters of hot pixels: square patches of sensor pixels sharing one dark-current rate (e-/s), before shot noise
CLUSTER_MAX = 4  # clusters of hot pixels: the largest side of a patch (sensor pixels)
ROW_BURST = 1 << 67  # burst rows: sensor rows read with extra white noise, at new rows in every frame (interference bursts during readout)
ROW_MAP = 1 << 68  # row-noise map: extra row noise of its own level per row block of the measured frame
ROW_SPIKES = 1 << 69  # row glitches: sensor rows offset far in one frame, at new rows in every frame
COL_BURST = 1 << 70  # burst columns: sensor columns read with extra white noise, at new columns in every frame
FULL_WELL = 1 << 71  # full well: a pixel holds at most its own full well of electrons (a seeded spread about the mean)
COL_GROUP = 1 << 72  # column groups: groups of adjacent sensor columns sharing an offset, new in every frame
ROW_PAIR = 1 << 74  # row pairs: a row offset shared by the two sensor rows of a Bayer row pair (a two-row readout), new in every frame
DARK_ROW_NOISE = 1 << 75  # exposure row noise: row offsets whose variance grows with the exposure, new in every frame
ROW_TAP = 1 << 76  # row noise per readout tap: each column tap's own offset per sensor row, new in every frame
BLACK_STEP = 1 << 77  # black steps: the black level steps from a row drawn per frame on, by a size drawn per frame
MASKED = 1 << 78  # masked lines: the sensor lines at the frame's edges get no light (optically black rows and columns)
COL_TAP = 1 << 79  # column noise per readout tap: each sensor column's offset, new in every frame, with its column tap's std
CHARGE_SHARE_DIAG = 1 << 80  # charge sharing with the four diagonal raw neighbours as well (with CHARGE_SHARE)
FIXED_MAP = 1 << 81  # measured fallback: the measured fixed map itself, a fine bilinear grid of offsets over the measured frame
BLACK_RAMP = 1 << 73  # black ramps: the black level a linear ramp down the sensor rows and across the columns, a new slope in every frame
BANK_PERIOD_MAX = 16  # readout banks: the longest period (sensor lines)
TAP_EDGES = 7  # edges per axis of the readout taps' grid (up to 8 x 8 taps)
READ_MAP_BLOCKS = 8  # row and column blocks of the read-noise map (over the measured frame)
DEAD_LEVELS = 8  # stuck levels of the dead pixels: equally likely, one per pixel
DNL_PERIOD_MAX = 64  # ADC differential non-linearity: the longest period of its decision levels (codes)
DRIFT_OCTAVES = 8  # row drift: octave j has nodes every 2^(j + 1) sensor rows



def flag_words(flags: int) -> tuple[int, int]:
    """(word 0, word 1) of a stage-flag set: bits 0 .. 62 and bits 63 .. 125, shifted down."""
    if not 0 <= flags < 1 << (2 * WORD_BITS):
        raise ValueError(f"stage flags must be in [0, 2^{2 * WORD_BITS}), got {flags}")
    return flags & ((1 << WORD_BITS) - 1), flags >> WORD_BITS


COLUMNS = (
    "k", "ratio",
    "prnu_sigma",
    "dark_e", "dsnu_log", "dark_c0", "dark_c1", "dark_c2", "dark_c3",  # dark current: electrons, DSNU, each channel's relative rate
    "sigma_tl", "lambda", "sigma_g",
    "sigma_r",
    "col_sigma", "col_fixed",
    "fpn_sigma", "fpn_record",
    "hot_density", "hot_median", "hot_log_std",
    "step_dn",
    "bias_r", "bias_g1", "bias_b", "bias_g2",
    "ble_sigma", "ble_channel_sigma",
    "clip_floor",
    "lowfreq_sigma", "lowfreq_gh", "lowfreq_gw",
    "codemap_record_c0", "codemap_record_c1", "codemap_record_c2", "codemap_record_c3",  # code map: record per packed channel (-1: none)
    "fpn_oy", "fpn_ox", "fpn_h", "fpn_w",  # FPN shading window in sensor pixels (fpn_h 0: the input is the sensor)
    "readq_record", "readq_scale",
    "lines_row_density", "lines_col_density", "lines_median", "lines_log_std", "lines_negative",
    "fpn_gh", "fpn_gw",  # FPN shading grid size (the grids table may be padded to a larger one)
    "glow_s", "glow_record", "glow_oy", "glow_ox", "glow_h", "glow_w", "glow_gh", "glow_gw",  # exposure, grid, window
    "nl_c0", "nl_c1", "nl_c2", "nl_c3",  # gain non-linearity: compression per DN of signal, per packed channel
    "sensor",  # sensor instance of the fixed patterns (an integer; 0: the profile's own)
    *(f"xt_{i}" for i in range(7)),  # correlated read noise: the kernel's tap (DN) at each of XTALK_TAPS
    "band_f0", "band_f1", "band_f2", "band_a0", "band_a1", "band_a2",  # banding tones: cycles per sensor row, amplitude (DN)
    "rowfix_sigma",  # fixed row pattern: std of the sensor-row offsets (DN)
    "rowch_sigma",  # row noise of each channel's own (DN)
    "rmap_c0", "rmap_c1", "rmap_c2", "rmap_c3",  # read-noise map: extra sigma per packed channel (DN)
    *(f"rmap_y{i}" for i in range(READ_MAP_BLOCKS)), *(f"rmap_x{i}" for i in range(READ_MAP_BLOCKS)),  # ... per row block, per column block (DN)
    "rmap_oy", "rmap_ox", "rmap_h", "rmap_w",  # its window in packed pixels (rmap_h 0: the input is the sensor)
    "shared_sigma",  # shared-pixel readout: the noise a Bayer tile's four pixels share (DN)
    "rts_density", "rts_median", "rts_log_std", "rts_high",  # telegraph pixels: share, step (DN), share of frames high
    "dead_density", *(f"dead_l{i}" for i in range(DEAD_LEVELS)),  # dead pixels: share, stuck levels (DN)
    *(f"drift_a{j}" for j in range(DRIFT_OCTAVES)),  # row drift: std of each octave's nodes (DN)
    "cband_f0", "cband_f1", "cband_f2", "cband_a0", "cband_a1", "cband_a2",  # column banding: cycles per sensor column, amplitude (DN)
    "dhot_density", "dhot_e", "dhot_log_std",  # hot pixels of dark current: share, median electrons this exposure, log-normal spread
    "colgain_sigma",  # column gain non-uniformity: std of the sensor columns' relative gains
    "dband_fx0", "dband_fx1", "dband_fx2", "dband_fy0", "dband_fy1", "dband_fy2",  # diagonal banding: cycles per sensor column, per sensor row
    "dband_a0", "dband_a1", "dband_a2",  # ... amplitude (DN)
    "dcol_density", "dcol_e", "dcol_log_std",  # leaky columns: share of sensor columns, median electrons this exposure, log-normal spread
    "dark_offset",  # black-level shift this exposure (DN)
    "spike_density", "spike_median", "spike_log_std",  # impulsive noise: share of pixels per frame, median (DN), log-normal spread
    "crts_density", "crts_median", "crts_log_std", "crts_high",  # column telegraph: share of sensor columns, step (DN), spread, share high
    "read_gain",  # frame-to-frame read-noise level: this frame's factor on the base read noise
    "frame_gain",  # frame-to-frame gain: this frame's factor on the photo signal
    "lmap_record", "lmap_gh", "lmap_gw", "lmap_oy", "lmap_ox", "lmap_h", "lmap_w",  # line profiles: grids record, window
    "lmap_lh", "lmap_lw",  # ... and the measured profiles' lengths (packed rows, packed columns)
    "rowgain_fixed", "rowgain_frame",  # row gain: std of the sensor rows' relative gains, fixed and per frame
    "ggrid_record", "ggrid_py", "ggrid_px", "ggrid_oy", "ggrid_ox",  # gain grid: first grids record, period, phase (packed pixels)
    "black_drift",  # black-level drift: this frame's offset (DN), all channels
    "share_c", "share_x", "share_y",  # charge sharing: weights of the pixel's own, a horizontal and a vertical neighbour's shot deviation
    "share_d1", "share_d2",  # ... and of a diagonal neighbour's: along (1, 1) and along (1, -1)
    "fmap_record", "fmap_oy", "fmap_ox", "fmap_h", "fmap_w", "fmap_gh", "fmap_gw",  # measured fixed map: its grid record, window, size
    "dband_f0", "dband_f1", "dband_f2",  # diagonal banding: amplitude (DN) of each tone's part fixed in phase (the sensor's)
    "drow_density", "drow_e", "drow_log_std",  # leaky rows: share of sensor rows, median electrons this exposure, log-normal spread
    "noisy_density", "noisy_median", "noisy_log_std",  # noisy pixels: share, median extra noise (DN), log-normal spread
    "drts_density", "drts_e", "drts_log_std", "drts_high",  # dark-current telegraph: share, median step (electrons this exposure), spread, share high
    "ncol_density", "ncol_median", "ncol_log_std",  # noisy columns: share of sensor columns, median extra noise (DN), log-normal spread
    "rrts_density", "rrts_median", "rrts_log_std", "rrts_high",  # row telegraph: share of sensor rows, step (DN), spread, share high
    "tap_sigma",  # readout taps: offset std per frame and tap (DN)
    *(f"tap_c{i}" for i in range(TAP_EDGES)), *(f"tap_r{i}" for i in range(TAP_EDGES)),  # ... edges, fractions of the sensor lines (2: none)
    "tap_oy", "tap_ox", "tap_h", "tap_w",  # ... the input's window of the measured frame (packed pixels; 0: the input is the sensor)
    "tgain_record",  # readout taps' gains: grids record (taps' rows x taps' columns)
    *(f"tgain_c{i}" for i in range(TAP_EDGES)), *(f"tgain_r{i}" for i in range(TAP_EDGES)),  # ... edges, fractions of the sensor lines (2: none)
    "tgain_oy", "tgain_ox", "tgain_h", "tgain_w",  # ... the input's window of the measured frame (packed pixels; 0: the input is the sensor)
    "lgain_row_density", "lgain_col_density", "lgain_median", "lgain_log_std", "lgain_negative",  # gain defect lines: densities, median gain offset (fraction), spread, share dim
    "dark_factor",  # dark-signal drift: this frame's factor on the dark signal
    "dnl_period", *(f"dnl_e{i}" for i in range(DNL_PERIOD_MAX)),  # ADC non-linearity: period (codes), decision-level offsets (DN)
    "dark_noise",  # exposure noise: its std this exposure (DN)
    "trap_dn",  # charge trapping: the traps' capacity (DN at this K)
    "gain_noise",  # pixel gain noise: its relative std at this K
    "pgain_density", "pgain_median", "pgain_log_std", "pgain_negative",  # gain defect pixels: share, median gain offset (fraction), spread, share dim
    "row_h",  # heavy-tailed row noise: Tukey h of the row draws at this K
    "ffield_sigma", "ffield_gh", "ffield_gw",  # measured fixed field: std (DN), grid rows and columns
    "stuck_z0", "stuck_z1", "stuck_z2", "stuck_z3", "stuck_low", "stuck_high",  # stuck bits: raw code of 0 DN per channel, masks
    "spike_negative",  # impulsive noise: share of the events that are dark (a lost charge packet)
    "bank_cp", "bank_rp",  # readout bank offsets: column and row periods (sensor lines)
    *(f"bank_c{i}" for i in range(BANK_PERIOD_MAX)), *(f"bank_r{i}" for i in range(BANK_PERIOD_MAX)),  # ... offsets per bank (DN)
    *(f"cdrift_a{j}" for j in range(DRIFT_OCTAVES)),  # column drift: std of each octave's nodes (DN)
    "repeat_density",  # repeated rows: share of the sensor rows of a frame that repeat the same colour's row above
    "bnoise_cp", *(f"bnoise_c{i}" for i in range(BANK_PERIOD_MAX)),  # readout bank noise: period (sensor columns), extra std per bank (DN)
    "dclus_density", "dclus_e", "dclus_log_std", "dclus_size",  # hot clusters: seeds per sensor pixel, median electrons this exposure, log spread, side
    "burst_density", "burst_sigma",  # burst rows: share of a frame's sensor rows, extra std (DN)
    "dead_col_density", "dead_row_density", "dead_partial", "dead_to_end",  # dead lines: shares of sensor columns and rows, share partial, of those the share reaching the end
    "dead_cut_lo", "dead_cut_hi",  # ... the range of a partial line's break (fractions of the line)
    *(f"rowmap_y{i}" for i in range(READ_MAP_BLOCKS)), "rowmap_oy", "rowmap_h",  # row-noise map: extra std per row block (DN), window
    "hot_tile_density",  # hot pixels: share of the 2x2 tiles (packed positions) hot in all four pixels
    *(f"rmap_ye{i}" for i in range(READ_MAP_BLOCKS - 1)), *(f"rmap_xe{i}" for i in range(READ_MAP_BLOCKS - 1)),  # read-noise map: block edges (fractions of its frame; 2: none)
    "dsnu_col_log",  # dark current: log-normal sigma of the sensor columns' factors on the rate (column DSNU)
    "rmap_cell_record",  # read-noise map: grids record of its cells' extra variance (row block x column block, DN^2; -1: none)
    "rspike_density", "rspike_median", "rspike_log_std", "rspike_negative",  # row glitches: share of a frame's sensor rows, median offset (DN), log spread, share negative
    "col_rho",  # column noise: correlation of a column's offsets in consecutive frames of a sequence (0: new in every frame)
    "lines_partial", "lines_to_end", "lines_cut_lo", "lines_cut_hi",  # defect lines: share offset over a part, of those the share reaching the end, range of the break (fractions)
    "cburst_density", "cburst_sigma",  # burst columns: share of a frame's sensor columns, extra white noise (DN)
    "well_e", "well_spread",  # full well: mean capacity (electrons), relative spread over the pixels
    "rpair_sigma",  # row pairs: the shared offset's std (DN)
    "dark_row_sigma",  # exposure row noise: the row offsets' std at this exposure (DN)
    "ramp_row", "ramp_col",  # black ramps: the slopes' std, DN per sensor row and per sensor column
    "cgroup_sigma", "cgroup_width", "cgroup_start",  # column groups: the offset's std (DN), sensor columns per group, first group's start (< width)
    "rtap_sigma", *(f"rtap_c{i}" for i in range(TAP_EDGES)), "rtap_ox", "rtap_w",  # row noise per tap: std (DN), column edges (fractions; 2: none), window
    "mask_top", "mask_bottom", "mask_left", "mask_right",  # masked lines: sensor lines without light at each edge (0: none on this input)
    "bstep_at", "bstep_dn",  # black step: this frame's first stepped sensor row (fraction of the input's), its size (DN)
    "ggrid_conv",  # gain grid: share of the log gain applied after shot noise (0: optical, before it; 1: a conversion gain)
    "colgain_frame",  # column gain: std of each sensor column's gain drawn anew in every frame (fraction of the signal)
    *(f"ctap_s{i}" for i in range(TAP_EDGES + 1)),  # column noise per tap: each column tap's std (DN) ...
    *(f"ctap_c{i}" for i in range(TAP_EDGES)), "ctap_ox", "ctap_w",  # ... its column edges (fractions; 2: none), window
    "dsnu_row_log",  # dark current: log-normal sigma of the sensor rows' factors on the rate (row DSNU)
)
COLUMN = {name: i for i, name in enumerate(COLUMNS)}

SENSORS = 1 << 20  # sensor instances a sample may draw: its fixed patterns start at instance x (plane size)
READ_TABLE_Z = 6.0  # a read_lut row holds values on a uniform grid of normal scores in [-READ_TABLE_Z, READ_TABLE_Z]
N_COLUMNS = len(COLUMNS)

# Random stream slots (one 63-bit key each, per call or per fixed pattern).
STREAMS = (
    "shot", "shot_rest", "shot_coarse", "read", "row", "col", "quant", "ble",
    "prnu_pattern", "dsnu_pattern", "fpn_pattern", "lowfreq", "hot_where", "hot_size", "col_pattern",
    "lines_row", "lines_col", "xtalk", "band", "row_pattern", "row_channel", "read_map", "shared",
    "rts_where", "rts_size", "rts_state", "dead_where", "dead_level", "row_drift", "row_drift_phase",
    "col_band", "dhot_where", "dhot_size", "colgain_pattern", "diag_band", "dcol_where", "dcol_size",
    "spike_where", "spike_size", "crts_where", "crts_size", "crts_state", "rowgain_pattern", "rowgain_frame",
    "drow_where", "drow_size", "noisy_where", "noisy_size", "noisy_read",
    "drts_where", "drts_size", "drts_state", "ncol_where", "ncol_size", "ncol_read",
    "rrts_where", "rrts_size", "rrts_state", "tap", "lgain_row", "lgain_col", "dark_noise", "gain_noise", "pgain", "ffield",
    "col_drift", "col_drift_phase", "row_repeat", "bank_noise", "dclus_where", "dclus_size",
    "burst_row", "burst_noise", "dead_col", "dead_row", "row_map",
    "hot_tile_where", "hot_tile_size", "dsnu_col_pattern", "rspike_where", "rspike_size", "lines_row_cut", "lines_col_cut",
    "burst_col", "burst_col_noise", "well_pattern", "col_group", "black_ramp", "row_pair", "dark_row_noise",
    "row_tap", "colgain_frame", "col_tap", "dsnu_row_pattern",
)
STREAM = {name: i for i, name in enumerate(STREAMS)}
N_STREAMS = len(STREAMS)

# Raw-mosaic lags (rows, columns) of the correlated read noise: the horizontal and vertical
# neighbours, both diagonals (a 2x2 shared-pixel readout) and the next pixel of the same
# colour along each axis.
XTALK_LAGS = ((0, 1), (1, 0), (1, 1), (1, -1), (0, 2), (2, 0))
XTALK_TAPS = ((0, 0),) + XTALK_LAGS  # the correlated read noise's kernel: the pixel itself and the lags behind it
BAND_TONES = 3  # banding tones a profile may hold (along the rows; as many along the columns)
FIXED_PHASE = 1 << 62  # counter base of a sensor's fixed tone phases (sensor * BAND_TONES + j): apart from the per-frame ones
XTALK_PAD = 2  # raw pixels of margin in the draw index, so that a lag's neighbour index is never negative

# Packed (R, G1, B, G2): which of a 2x2 tile's sensor rows / columns a channel lies on.
ROW_SET = (0, 0, 1, 1)
COLUMN_SET = (0, 1, 1, 0)
CHANNEL_AT = ((0, 1), (3, 2))  # the packed channel of a raw pixel, by (row, column) parity
NEIGHBOURS = ((0, -1), (0, 1), (-1, 0), (1, 0), (-1, -1), (1, 1), (-1, 1), (1, -1))  # raw (dy, dx) of the neighbours charge is shared with: the four sides, then the diagonals
