"""Read one raw frame from any supported file format into a :class:`Frame`.

Formats (chosen by file extension):

* camera raw files through rawpy/LibRaw: ``.dng .cr2 .cr3 .nef .nrw .arw .srf .sr2 .raf
  .orf .rw2 .pef .srw .3fr .iiq .erf .kdc .mrw .x3f``; black/white levels and the CFA come
  from the file, ISO and exposure time from its EXIF;
* ``.npy`` (a 2-D array) and ``.npz`` (array ``mosaic`` or ``raw``, or the only array; may
  also hold scalars ``black_level``, ``white_level``, ``cfa``, ``iso``, ``exposure_s``);
* single-channel 8/16-bit ``.tif/.tiff`` (tifffile) and ``.png`` (imageio);
* headerless ``.raw/.bin``: needs ``width``, ``height`` and ``dtype`` (default ``<u2``,
  little-endian uint16). ``.raw`` is never handed to LibRaw, which would guess a camera
  layout from the file size alone.

Keyword arguments override what the file says (e.g. an ISO missing from EXIF); levels and
CFA that neither the file nor the caller give are an error, never a guess.
"""
from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np

from .frame import Frame

RAWPY_EXTENSIONS = (
    ".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".raf", ".orf",
    ".rw2", ".pef", ".srw", ".3fr", ".iiq", ".erf", ".kdc", ".mrw", ".x3f", ".rwl", ".mef", ".mos",
)
NUMPY_EXTENSIONS = (".npy", ".npz")
IMAGE_EXTENSIONS = (".tif", ".tiff", ".png")
HEADERLESS_EXTENSIONS = (".raw", ".bin")
SUPPORTED_EXTENSIONS = RAWPY_EXTENSIONS + NUMPY_EXTENSIONS + IMAGE_EXTENSIONS + HEADERLESS_EXTENSIONS


def _positive_int(value, name, where):
    try:
        out = int(value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {name} must be a positive integer, got {value!r}") from None
    if out <= 0 or out != float(value):
        raise ValueError(f"{where}: {name} must be a positive integer, got {value!r}")
    return out


def parse_dtype(dtype, where="dtype") -> np.dtype:
    """A headerless-file sample type; multi-byte types without a byte order are little-endian.

    Accepts NumPy names (``uint16``, ``<u2``, ``>u2``, ``float32``) and ``uint16le/uint16be``.
    """
    text = str(dtype).strip().lower() if not isinstance(dtype, np.dtype) else None
    order = None
    if text is not None:
        for suffix, bo in (("le", "<"), ("be", ">")):
            if text.endswith(suffix) and text[:-len(suffix)] in ("uint16", "int16", "uint32", "int32", "float32", "float64"):
                text, order = text[:-len(suffix)], bo
    try:
        out = np.dtype(text if text is not None else dtype)
    except TypeError:
        raise ValueError(f"{where}: dtype must be a NumPy sample type like 'uint16' or '<u2', got {dtype!r}") from None
    if not (np.issubdtype(out, np.integer) or np.issubdtype(out, np.floating)):
        raise ValueError(f"{where}: dtype must be an integer or float type, got {dtype!r}")
    if order is not None:
        out = out.newbyteorder(order)
    elif out.byteorder == "=" and out.itemsize > 1:
        out = out.newbyteorder("<")
    return out


def _read_headerless(path: Path, width, height, dtype):
    where = str(path)
    if width is None or height is None:
        raise ValueError(f"{where}: a headerless raw file needs width and height (keyword arguments or manifest columns)")
    width = _positive_int(width, "width", where)
    height = _positive_int(height, "height", where)
    dt = parse_dtype(dtype if dtype is not None else "<u2", where)
    expected = width * height * dt.itemsize
    size = path.stat().st_size
    if size < expected:
        raise ValueError(f"{where}: file is truncated: {size} bytes, expected {expected} for {width}x{height} {dt.str}")
    if size > expected:
        raise ValueError(f"{where}: file has {size} bytes, expected {expected} for {width}x{height} {dt.str}; wrong size or a header")
    data = np.fromfile(path, dtype=dt, count=width * height).reshape(height, width)
    return data.astype(dt.newbyteorder("=")), {}


def _scalar(value):
    value = np.asarray(value)
    if value.dtype.kind in "US":
        return str(value.item())
    return value.item() if value.ndim == 0 else tuple(value.tolist())


_NPY_HEADER = threading.Lock()  # np.load parses a header with ast.literal_eval, which CPython 3.11 can fail in threads (SystemError, cpython gh-106905)


def _read_numpy(path: Path):
    where = str(path)
    try:
        with _NPY_HEADER:  # the header only: a .npy's data is read after, from its memory map
            loaded = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise ValueError(f"{where}: cannot read as NumPy {path.suffix} file: {exc}") from None
    if isinstance(loaded, np.ndarray):
        return np.array(loaded), {}
    with _NPY_HEADER, loaded:  # every array of a .npz has a header of its own
        return _npz_frame(loaded, where)


def _npz_frame(loaded, where: str):
    meta = {}
    names = list(loaded.files)
    key = next((k for k in ("mosaic", "raw") if k in names), None)
    arrays = [k for k in names if k not in ("black_level", "white_level", "cfa", "iso", "exposure_s")]
    if key is None:
        if len(arrays) != 1:
            raise ValueError(f"{where}: .npz must hold an array named 'mosaic' or 'raw' (or exactly one array), got {names}")
        key = arrays[0]
    data = loaded[key]
    for name in ("black_level", "white_level", "cfa", "iso", "exposure_s"):
        if name in names:
            meta[name] = _scalar(loaded[name])
    return data, meta


def _read_image(path: Path):
    where = str(path)
    try:
        if path.suffix.lower() in (".tif", ".tiff"):
            import tifffile

            data = tifffile.imread(path)
        else:
            import imageio.v3 as iio

            data = iio.imread(path)
    except Exception as exc:  # the image libraries raise many types for a bad file
        raise ValueError(f"{where}: cannot read as {path.suffix} image: {exc}") from None
    data = np.asarray(data)
    if data.ndim != 2:
        raise ValueError(f"{where}: expected a single-channel Bayer image (H, W), got shape {data.shape}; demosaicked/RGB images cannot be calibrated")
    if data.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{where}: expected an 8- or 16-bit integer image, got dtype {data.dtype}")
    return data, {}


def _rawpy_cfa(raw, where) -> str:
    desc = raw.color_desc.decode()
    colors = np.asarray(raw.raw_colors_visible[:2, :2])
    if raw.num_colors not in (3, 4) or desc[:3] != "RGB":
        raise ValueError(f"{where}: not a Bayer RGB sensor (colour description {desc!r})")
    cfa = "".join(desc[int(c)] for c in colors.ravel())
    if cfa not in ("RGGB", "BGGR", "GRBG", "GBRG"):
        raise ValueError(f"{where}: CFA {cfa!r} is not a 2x2 Bayer pattern (X-Trans and others are not supported)")
    return cfa, colors


def _read_rawpy(path: Path):
    import rawpy

    from ..bayer import cfa_offsets

    where = str(path)
    try:
        raw = rawpy.imread(str(path))
    except (rawpy.LibRawError, OSError) as exc:
        raise ValueError(f"{where}: LibRaw cannot read this camera raw file: {type(exc).__name__}: {exc}") from None
    with raw:
        try:
            data = np.array(raw.raw_image_visible, copy=True)
        except rawpy.LibRawError as exc:
            raise ValueError(f"{where}: LibRaw cannot unpack the raw data: {type(exc).__name__}: {exc}") from None
        cfa, colors = _rawpy_cfa(raw, where)
        per_index = list(raw.black_level_per_channel)
        black = tuple(float(per_index[int(colors[r, c])]) for r, c in cfa_offsets(cfa))
        meta = {
            "cfa": cfa,
            "black_level": black[0] if len(set(black)) == 1 else black,
            "white_level": float(raw.white_level),
        }
        other = raw.other
        if other.iso_speed and other.iso_speed > 0:
            meta["iso"] = float(other.iso_speed)
        if other.shutter_speed and other.shutter_speed > 0:
            meta["exposure_s"] = float(other.shutter_speed)
    h, w = data.shape
    return data[: h - h % 2, : w - w % 2], meta


def read_frame(path, *, width=None, height=None, dtype=None, cfa=None, black_level=None, white_level=None,
               iso=None, exposure_s=None) -> Frame:
    """Read one raw frame (any supported format) into a :class:`Frame`.

    Parameters
    ----------
    path : file path; the extension picks the reader (see module docstring).
    width, height, dtype : layout of a headerless ``.raw/.bin`` file (ignored otherwise).
    cfa, black_level, white_level : levels (raw codes) and CFA; override the file's.
    iso, exposure_s : capture settings; override the file's EXIF.

    Raises
    ------
    FileNotFoundError : no such file.
    ValueError : unsupported extension, unreadable/truncated file, or metadata that
        neither the file nor the caller give.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"raw frame {str(path)!r} does not exist")
    ext = path.suffix.lower()
    if ext in HEADERLESS_EXTENSIONS:
        # Always headerless: LibRaw would "recognize" such a file by its size alone and
        # silently apply some camera's layout and levels (seen on a 1920x1080 uint16 dump).
        data, meta = _read_headerless(path, width, height, dtype)
    elif ext in RAWPY_EXTENSIONS:
        data, meta = _read_rawpy(path)
    elif ext in NUMPY_EXTENSIONS:
        data, meta = _read_numpy(path)
    elif ext in IMAGE_EXTENSIONS:
        data, meta = _read_image(path)
    else:
        raise ValueError(f"{str(path)}: unsupported file extension {ext!r}; supported: {', '.join(SUPPORTED_EXTENSIONS)}")
    given = {"cfa": cfa, "black_level": black_level, "white_level": white_level, "iso": iso, "exposure_s": exposure_s}
    for key, value in given.items():
        if value is not None:
            meta[key] = value
    missing = [k for k in ("cfa", "black_level", "white_level") if meta.get(k) is None]
    if missing:
        raise ValueError(f"{str(path)}: the file does not store {', '.join(missing)}; give them (read_frame keywords or manifest columns)")
    if data.ndim != 2:
        raise ValueError(f"{str(path)}: expected a 2-D Bayer mosaic, got shape {data.shape}")
    return Frame(mosaic=data, black_level=meta["black_level"], white_level=meta["white_level"], cfa=meta["cfa"],
                 iso=meta.get("iso"), exposure_s=meta.get("exposure_s"), path=os.fspath(path))
