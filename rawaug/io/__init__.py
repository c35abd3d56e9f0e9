"""Reading raw frames (camera raw files, NumPy, 16-bit TIFF/PNG, headerless) and CSV manifests."""
from .frame import Frame
from .manifest import KINDS, ManifestEntry, find_flat_pairs, group_by_iso, read_manifest
from .readers import SUPPORTED_EXTENSIONS, parse_dtype, read_frame

__all__ = [
    "Frame", "ManifestEntry", "KINDS", "SUPPORTED_EXTENSIONS",
    "read_frame", "read_manifest", "group_by_iso", "find_flat_pairs", "parse_dtype",
]
