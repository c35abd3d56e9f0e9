"""The training app: the ELD U-Net denoiser trained on on-device synthetic noise (Lightning)."""
from .callbacks import DenoisedWriter
from .data import RawDenoiseData
from .eld import ELD
from .module import DenoiseModule
from .sid import SIDSony
from .sources import CleanFolder, NoisyFolder, PhotoFolder, Source
from .unet import UNet

__all__ = ["DenoiseModule", "RawDenoiseData", "Source", "CleanFolder", "NoisyFolder", "PhotoFolder", "SIDSony", "ELD", "UNet", "DenoisedWriter"]
