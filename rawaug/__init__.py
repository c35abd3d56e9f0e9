"""rawaug: physics-based low-light raw noise augmentation, calibration and closed-loop checking."""
from .augment import PAPER_MODELS, RawNoiseAugment, parse_model
from .bayer import pack, unpack
from .profile import BUILTIN_PROFILES, NoiseProfile

__all__ = ["RawNoiseAugment", "NoiseProfile", "BUILTIN_PROFILES", "PAPER_MODELS", "parse_model", "pack", "unpack"]
__version__ = "0.1.0"
