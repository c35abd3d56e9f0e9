"""Write a minimal, real CFA DNG (uncompressed, 16-bit) that LibRaw/rawpy reads: for tests,
demos and exporting synthesized frames. ISO and exposure go into an EXIF IFD."""
from __future__ import annotations

import os
import struct
import tempfile
from fractions import Fraction
from pathlib import Path

import numpy as np

_CFA_CODES = {"R": 0, "G": 1, "B": 2}
_EXIF_PLACEHOLDER = 34666  # written by tifffile, then renamed to ExifIFD (34665), which tifffile refuses


def write_dng(path, mosaic, *, cfa: str, black_level: int, white_level: int, iso: float | None = None,
              exposure_s: float | None = None, camera: str = "rawaug synthetic") -> None:
    """Write ``mosaic`` (H, W) raw codes as a CFA DNG, atomically.

    Tags: NewSubFileType 0, PhotometricInterpretation 32803 (CFA), CFARepeatPatternDim,
    CFAPattern, DNGVersion 1.4, UniqueCameraModel, BlackLevel, WhiteLevel; EXIF ISOSpeedRatings
    and ExposureTime when given.
    """
    import tifffile

    data = np.asarray(mosaic)
    if data.ndim != 2 or data.dtype != np.uint16:
        raise ValueError(f"mosaic must be a 2-D uint16 array, got shape {data.shape} dtype {data.dtype}")
    cfa = str(cfa).upper()
    if sorted(cfa) != ["B", "G", "G", "R"]:
        raise ValueError(f"cfa must be a 2x2 Bayer pattern like 'RGGB', got {cfa!r}")
    tags = [
        (33421, "H", 2, (2, 2), True),
        (33422, "B", 4, tuple(_CFA_CODES[c] for c in cfa), True),
        (50706, "B", 4, (1, 4, 0, 0), True),
        (50708, "s", 0, camera, True),
        (50714, "I", 1, (int(black_level),), True),
        (50717, "I", 1, (int(white_level),), True),
        (271, "s", 0, "rawaug", True),
        (272, "s", 0, camera, True),
    ]
    exif = []
    if exposure_s is not None:
        if not float(exposure_s) > 0:
            raise ValueError(f"exposure_s must be > 0 seconds, got {exposure_s!r}")
        t = Fraction(float(exposure_s)).limit_denominator(1_000_000)
        exif.append((33434, 5, (t.numerator, t.denominator)))
    if iso is not None:
        exif.append((34855, 3, int(round(float(iso)))))
    if exif:
        tags.append((_EXIF_PLACEHOLDER, "I", 1, (0,), True))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".dng", dir=path.parent)
    os.close(fd)
    try:
        tifffile.imwrite(tmp, data, photometric=32803, subfiletype=0, extratags=tags, bitspersample=16,
                         byteorder="<")
        if exif:
            _append_exif(tmp, exif)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _append_exif(path, entries):
    import tifffile

    with tifffile.TiffFile(path) as tif:
        offset = tif.pages[0].tags[_EXIF_PLACEHOLDER].valueoffset
    buf = bytearray(Path(path).read_bytes())
    if struct.unpack("<H", buf[offset - 8: offset - 6])[0] != _EXIF_PLACEHOLDER:
        raise RuntimeError("unexpected TIFF layout while adding the EXIF IFD")
    buf[offset - 8: offset - 6] = struct.pack("<H", 34665)
    if len(buf) % 2:
        buf += b"\0"
    start = len(buf)
    entries = sorted(entries)
    extra_at = start + 2 + 12 * len(entries) + 4
    ifd, extra = struct.pack("<H", len(entries)), b""
    for tag, typ, value in entries:
        if typ == 5:  # RATIONAL: stored after the IFD
            ifd += struct.pack("<HHII", tag, 5, 1, extra_at + len(extra))
            extra += struct.pack("<II", *value)
        else:  # SHORT, inline
            ifd += struct.pack("<HHIHH", tag, 3, 1, value, 0)
    buf += ifd + struct.pack("<I", 0) + extra
    buf[offset: offset + 4] = struct.pack("<I", start)
    Path(path).write_bytes(buf)
