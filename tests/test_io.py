"""Frame reading: every supported format, the manifest, and clear errors on bad input."""
import numpy as np
import pytest
import tifffile

from rawaug.bayer import pack
from rawaug.io import Frame, find_flat_pairs, group_by_iso, read_frame, read_manifest
from rawaug.io.dng import write_dng


def _mosaic(h=8, w=12, seed=0):
    return np.random.default_rng(seed).integers(500, 4000, size=(h, w)).astype(np.uint16)


def test_frame_packs_and_normalizes_with_per_channel_black():
    m = _mosaic()
    f = Frame(m, (500, 501, 502, 503), 4095, "GRBG")
    dn = f.packed_dn()
    expected = pack(m, "GRBG").astype(np.float32) - np.array([500, 501, 502, 503], np.float32)[:, None, None]
    np.testing.assert_array_equal(dn, expected)
    np.testing.assert_allclose(f.packed_normalized(), dn / (4095 - 503))
    assert dn.dtype == np.float32 and f.packed_normalized().dtype == np.float32


@pytest.mark.parametrize("kwargs, match", [
    (dict(mosaic=np.zeros((3, 4)), black_level=0, white_level=1, cfa="RGGB"), "even"),
    (dict(mosaic=np.zeros((4, 4)), black_level=0, white_level=1, cfa="RGBG"), "cfa"),
    (dict(mosaic=np.zeros((4, 4)), black_level=5, white_level=4, cfa="RGGB"), "exceed"),
    (dict(mosaic=np.zeros((4, 4)), black_level=(1, 2), white_level=9, cfa="RGGB"), "4 values"),
    (dict(mosaic=np.zeros((4, 4)), black_level=0, white_level=9, cfa="RGGB", iso=-1), "iso"),
])
def test_frame_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Frame(**kwargs)


def test_headerless_raw_and_its_errors(tmp_path):
    m = _mosaic(6, 10)
    p = tmp_path / "f.raw"
    m.astype("<u2").tofile(p)
    f = read_frame(p, width=10, height=6, dtype="uint16", cfa="BGGR", black_level=64, white_level=1023, iso=400)
    np.testing.assert_array_equal(f.mosaic, m)
    assert (f.cfa, f.iso, f.black_level) == ("BGGR", 400.0, 64.0)
    big = tmp_path / "big.raw"
    m.astype(">u2").tofile(big)
    g = read_frame(big, width=10, height=6, dtype="uint16be", cfa="BGGR", black_level=0, white_level=65535)
    np.testing.assert_array_equal(g.mosaic, m)
    with pytest.raises(ValueError, match="needs width and height"):
        read_frame(p, cfa="BGGR", black_level=0, white_level=4095)
    (tmp_path / "cut.raw").write_bytes(p.read_bytes()[:-7])
    with pytest.raises(ValueError, match="truncated"):
        read_frame(tmp_path / "cut.raw", width=10, height=6, cfa="BGGR", black_level=0, white_level=4095)
    with pytest.raises(ValueError, match="does not store black_level, white_level"):
        read_frame(p, width=10, height=6, cfa="BGGR")


def test_numpy_tiff_png(tmp_path):
    import imageio.v3 as iio

    m = _mosaic()
    np.save(tmp_path / "a.npy", m)
    assert np.array_equal(read_frame(tmp_path / "a.npy", cfa="RGGB", black_level=0, white_level=4095).mosaic, m)
    np.savez(tmp_path / "b.npz", mosaic=m, black_level=np.array([1, 2, 3, 4]), white_level=4095, cfa="GBRG", iso=100)
    f = read_frame(tmp_path / "b.npz")
    assert (f.cfa, f.black_level, f.white_level, f.iso) == ("GBRG", (1.0, 2.0, 3.0, 4.0), 4095.0, 100.0)
    tifffile.imwrite(tmp_path / "c.tif", m)
    assert np.array_equal(read_frame(tmp_path / "c.tif", cfa="RGGB", black_level=0, white_level=4095).mosaic, m)
    iio.imwrite(tmp_path / "d.png", m)
    assert np.array_equal(read_frame(tmp_path / "d.png", cfa="RGGB", black_level=0, white_level=4095).mosaic, m)
    tifffile.imwrite(tmp_path / "rgb.tif", np.zeros((8, 8, 3), np.uint16))
    with pytest.raises(ValueError, match="single-channel"):
        read_frame(tmp_path / "rgb.tif", cfa="RGGB", black_level=0, white_level=4095)


def test_unreadable_and_unsupported(tmp_path):
    (tmp_path / "junk.dng").write_bytes(b"not a raw file at all" * 10)
    with pytest.raises(ValueError, match="LibRaw cannot read"):
        read_frame(tmp_path / "junk.dng")
    (tmp_path / "junk.npy").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="cannot read as NumPy"):
        read_frame(tmp_path / "junk.npy", cfa="RGGB", black_level=0, white_level=1)
    (tmp_path / "x.jpg").write_bytes(b"x")
    with pytest.raises(ValueError, match="unsupported file extension"):
        read_frame(tmp_path / "x.jpg")
    with pytest.raises(FileNotFoundError):
        read_frame(tmp_path / "missing.dng")


@pytest.mark.parametrize("cfa", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_real_dng_through_rawpy(tmp_path, cfa):
    """A DNG written by rawaug.io.dng and read back by LibRaw: pixels, CFA, levels, EXIF."""
    m = _mosaic(32, 48, seed=3)  # LibRaw refuses images narrower than ~22 pixels
    write_dng(tmp_path / "f.dng", m, cfa=cfa, black_level=512, white_level=16383, iso=3200, exposure_s=1 / 250)
    f = read_frame(tmp_path / "f.dng")
    np.testing.assert_array_equal(f.mosaic, m)
    assert f.cfa == cfa and f.black_level == 512.0 and f.white_level == 16383.0
    assert f.iso == 3200.0 and f.exposure_s == pytest.approx(1 / 250, rel=1e-6)
    assert read_frame(tmp_path / "f.dng", iso=100).iso == 100.0  # explicit values override EXIF


def test_manifest_parsing_grouping_and_pairs(tmp_path):
    m = _mosaic()
    for name in ("b1", "f1", "f2", "f3", "g1", "g2"):
        np.save(tmp_path / f"{name}.npy", m)
    (tmp_path / "m.csv").write_text(
        "# calibration set\n"
        "path,kind,iso,exposure_s,cfa,black_level,white_level\n"
        "b1.npy,bias,100,,RGGB,64 65 66 67,1023\n"
        "f1.npy,flat,100,0.01,RGGB,64,1023\n"
        "f2.npy,flat,100,0.01,RGGB,64,1023\n"
        "f3.npy,flat,100,0.02,RGGB,64,1023\n"
        "g1.npy,flat,200,0.01,RGGB,64,1023\n"
        "g2.npy,flat,200,0.01,RGGB,64,1023\n")
    entries = read_manifest(tmp_path / "m.csv")
    assert entries[0].black_level == (64, 65, 66, 67) and entries[0].path == str(tmp_path / "b1.npy")
    assert entries[0].read().black_level == (64.0, 65.0, 66.0, 67.0)
    groups = group_by_iso(entries)
    assert list(groups) == [100.0, 200.0] and len(groups[100.0]) == 4
    with pytest.warns(UserWarning, match="no partner"):
        pairs = find_flat_pairs([e for e in entries if e.kind == "flat"])
    assert [(a.path[-6:], b.path[-6:]) for a, b in pairs] == [("f1.npy", "f2.npy"), ("g1.npy", "g2.npy")]


def test_flats_under_listed_lights_pair_by_light(tmp_path):
    m = _mosaic()
    for name in ("b1", "f1", "f2", "f3", "f4"):
        np.save(tmp_path / f"{name}.npy", m)
    (tmp_path / "m.csv").write_text(
        "path,kind,iso,exposure_s,light\n"  # one exposure time, two lights, listed interleaved
        "b1.npy,bias,100,0.001,\n"
        "f1.npy,flat,100,0.01,0.5\n"
        "f2.npy,flat,100,0.01,1\n"
        "f3.npy,flat,100,0.01,0.5\n"
        "f4.npy,flat,100,0.01,1\n")
    entries = read_manifest(tmp_path / "m.csv")
    assert [e.light for e in entries] == [None, 0.5, 1.0, 0.5, 1.0]
    pairs = find_flat_pairs([e for e in entries if e.kind == "flat"])
    assert sorted((a.path[-6:], b.path[-6:]) for a, b in pairs) == [("f1.npy", "f3.npy"), ("f2.npy", "f4.npy")]


@pytest.mark.parametrize("body, match", [
    ("path,kind,iso\nb.npy,bias,\n", "missing ISO"),
    ("path,kind,iso\nb.npy,light,100\n", "kind must be one of"),
    ("path,kind,iso\nb.npy,flat,100\n", "needs exposure_s"),
    ("path,kind,iso,colour\nb.npy,bias,100,red\n", "unknown"),
    ("path,kind,iso,black_level\nb.npy,bias,100,1 2\n", "black_level"),
    ("path,kind,iso\nb.npy,bias,-5\n", "positive"),
    ("path,kind,iso,exposure_s,light\nf.npy,flat,100,0.01,0\n", "'light' must be a positive"),
    ("path,kind,iso,light\nb.npy,bias,100,1\n", "a bias frame has none"),
])
def test_manifest_errors(tmp_path, body, match):
    (tmp_path / "m.csv").write_text(body)
    with pytest.raises(ValueError, match=match):
        read_manifest(tmp_path / "m.csv")
