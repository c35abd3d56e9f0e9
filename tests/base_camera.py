"""The base camera's synthesis parameters at one gain, fixed (read, row and Gaussian scales at
their relations' medians, one sensor instance), shared by the effects' stage tests."""


def base_fixed(profile, k: float, sensor: int = 0, lam: float = 0.05, **more) -> dict:
    """``RawNoiseAugment(fixed=...)`` for ``profile`` at gain ``k`` (DN/e-), plus ``more``."""
    return {"k": k, "sigma_tl": profile.tukey_scale.median(k), "lambda": lam, "sigma_g": profile.gaussian_scale.median(k),
            "sigma_r": profile.row_scale.median(k), "sensor": sensor, **more}
