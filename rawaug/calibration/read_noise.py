"""Read noise of a bias residual by probability-plot correlation (PPCC): the Tukey-lambda
shape, its scale sigma_TL and the Gaussian sigma_G (DN), as ELD section 3.2 fits them."""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import stats

LAMBDA_GRID = np.round(np.arange(-0.5, 1.0 + 1e-9, 0.05), 4)  # PPCC coarse grid


@dataclass
class ReadNoiseEstimate:
    """Read noise of a row-corrected bias residual.

    lam : Tukey-lambda shape maximizing the probability-plot correlation (PPCC).
    sigma_tl : Tukey-lambda scale, DN (slope of the probability plot at ``lam``).
    sigma_g : Gaussian scale, DN (slope of the normal probability plot).
    r2_tukey, r2_gauss : R^2 of the two probability plots.
    ppcc_grid : (lambda, PPCC) on the coarse grid, for the PPCC plot.
    n_samples : values used (after subsampling).
    """

    lam: float
    sigma_tl: float
    sigma_g: float
    r2_tukey: float
    r2_gauss: float
    ppcc_grid: tuple = ()
    n_samples: int = 0
    std_dn: float = 0.0


def _tukey_ppf(p, lam):
    """Standard Tukey-lambda quantile function (same as scipy.stats.tukeylambda.ppf)."""
    if abs(lam) < 1e-9:
        return np.log(p) - np.log1p(-p)
    return (p**lam - (1.0 - p) ** lam) / lam


def _filliben(n):
    v = np.empty(n)
    v[-1] = 0.5 ** (1.0 / n)
    v[0] = 1.0 - v[-1]
    i = np.arange(2, n)
    v[1:-1] = (i - 0.3175) / (n + 0.365)
    return v


def _ppcc(sorted_x, osm, lam):
    q = _tukey_ppf(osm, lam)
    return float(np.corrcoef(q, sorted_x)[0, 1])


def sample_indices(n: int, max_samples: int | None, seed: int = 0) -> np.ndarray | None:
    """Indices of up to ``max_samples`` of ``n`` values drawn without replacement (None: all)."""
    if max_samples is None or n <= max_samples:
        return None
    return np.random.default_rng(seed).choice(n, size=int(max_samples), replace=False)


def subsample(values: np.ndarray, max_samples: int | None, seed: int = 0) -> np.ndarray:
    """Up to ``max_samples`` values drawn without replacement (all of them when fewer)."""
    flat = np.asarray(values).ravel()
    idx = sample_indices(flat.size, max_samples, seed)
    return (flat if idx is None else flat[idx]).astype(np.float64)


def estimate_read_noise(residual_dn, *, max_samples: int | None = 200_000, seed: int = 0) -> ReadNoiseEstimate:
    """Tukey-lambda read noise of a row-corrected residual (DN), by PPCC.

    ``lambda`` is found on a grid over [-0.5, 1] and refined with ``scipy.stats.ppcc_max``;
    ``sigma_TL`` is the least-squares slope of the sorted values against
    ``scipy.stats.tukeylambda.ppf`` at that lambda. ``max_samples`` random values are used
    (None: all); the benchmark shows what subsampling costs in accuracy.
    """
    x = np.sort(subsample(residual_dn, max_samples, seed))
    if x.size < 100:
        raise ValueError(f"read-noise fit needs at least 100 values, got {x.size}")
    if not np.all(np.isfinite(x)):
        raise ValueError("residual_dn holds NaN or Inf values")
    if x[0] == x[-1]:
        raise ValueError(f"residual_dn is constant ({x[0]}): no read noise to fit")
    osm = _filliben(x.size)
    grid = [(float(lam), _ppcc(x, osm, lam)) for lam in LAMBDA_GRID]
    best = max(range(len(grid)), key=lambda i: grid[i][1])
    lo = LAMBDA_GRID[max(best - 1, 0)]
    hi = LAMBDA_GRID[min(best + 1, len(LAMBDA_GRID) - 1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            lam = float(stats.ppcc_max(x, brack=(float(lo), float(LAMBDA_GRID[best]), float(hi)), dist="tukeylambda"))
        except ValueError:  # bracket condition not met at the grid edge: keep the grid value
            lam = float(LAMBDA_GRID[best])
    if not (LAMBDA_GRID[0] - 0.05 <= lam <= LAMBDA_GRID[-1] + 0.05) or _ppcc(x, osm, lam) < grid[best][1]:
        lam = float(LAMBDA_GRID[best])
    q = stats.tukeylambda.ppf(osm, lam)
    slope_tl, _, r_tl, _, _ = stats.linregress(q, x)
    z = stats.norm.ppf(osm)
    slope_g, _, r_g, _, _ = stats.linregress(z, x)
    return ReadNoiseEstimate(lam=lam, sigma_tl=float(slope_tl), sigma_g=float(slope_g), r2_tukey=float(r_tl**2),
                             r2_gauss=float(r_g**2), ppcc_grid=tuple(grid), n_samples=int(x.size), std_dn=float(x.std()))
