import numpy as np
import pytest
import torch

from rawaug.bayer import CFA_PATTERNS, pack, raw_to_normalized, unpack


@pytest.mark.parametrize("cfa", CFA_PATTERNS)
def test_pack_unpack_round_trip_numpy_and_torch(cfa):
    mosaic = np.arange(8 * 12, dtype=np.uint16).reshape(8, 12)
    packed = pack(mosaic, cfa)
    assert packed.shape == (4, 4, 6) and packed.dtype == np.uint16
    assert np.array_equal(unpack(packed, cfa), mosaic)
    t = torch.from_numpy(mosaic.astype(np.float32))[None]
    assert torch.equal(unpack(pack(t, cfa), cfa), t)


@pytest.mark.parametrize("cfa", CFA_PATTERNS)
def test_canonical_order_puts_colors_and_rows_in_place(cfa):
    colors = np.array(list(cfa)).reshape(2, 2)
    mosaic = np.tile(colors, (2, 2))
    packed = pack(mosaic, cfa)
    assert [packed[i, 0, 0] for i in range(4)] == ["R", "G", "B", "G"]
    rows = np.repeat(np.arange(4)[:, None], 4, axis=1)  # value = sensor row
    prow = pack(rows, cfa)
    assert np.array_equal(prow[0], prow[1]) and np.array_equal(prow[2], prow[3])
    cols = rows.T
    pcol = pack(cols, cfa)
    assert np.array_equal(pcol[0], pcol[3]) and np.array_equal(pcol[1], pcol[2])


def test_bad_cfa_and_odd_sizes_are_refused():
    with pytest.raises(ValueError, match="'RGBG'"):
        pack(np.zeros((4, 4)), "RGBG")
    with pytest.raises(ValueError, match="5x4"):
        pack(np.zeros((5, 4)), "RGGB")


def test_raw_to_normalized_per_channel_black():
    packed = np.full((4, 2, 2), 600.0)
    out = raw_to_normalized(packed, [512, 510, 514, 512], 16383)
    assert np.allclose(out[:, 0, 0], (600 - np.array([512, 510, 514, 512])) / (16383 - 514))
