"""The base camera's synthesis parameters at one gain, fixed (read, row and Gaussian scales at
their relations' medians, one sensor instance), shared by the effects' stage tests."""


def base_fixed(profile, k: float, sensor: int = 0, lam: float = 0.05, **more) -> dict:
    """``RawNoiseAugment(fixed=...)`` for ``profile`` at gain ``k`` (DN/e-), plus ``more``."""
    return {"k": k, "sigma_tl": profile.tukey_scale.median(k), "lambda": lam, "sigma_g": profile.gaussian_scale.median(k),
            "sigma_r": profile.row_scale.median(k), "sensor": sensor, **more}


def bias_stack(profile, effects, k: float, seed: int, n: int = 8, size=96, sensor: int = 0):
    """(n, 4, size, size) bias frames (DN; ``size`` may be (h, w)) of ``profile`` at gain ``k``
    with ``effects`` (token: entry), model G+R, one sensor instance."""
    import torch

    from rawaug import RawNoiseAugment

    for token, entry in effects.items():
        profile = profile.with_effect(token, entry)
    aug = RawNoiseAugment(profile, model="G+R", ratio=1.0, fixed=base_fixed(profile, k, sensor=sensor),
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        h, w = (size, size) if isinstance(size, int) else size
        return aug(torch.zeros(n, 4, h, w, dtype=torch.float64)).numpy() * profile.span_dn
