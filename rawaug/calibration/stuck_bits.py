"""Read noise through stuck ADC bits: the Tukey-lambda fit of bias codes whose bits of a mask
never move.

With bit ``b`` of every raw code stuck, a code that had it set (or clear) reads ``2^b`` away:
the histogram is a comb of runs and gaps, and a probability plot of the values fits a
Tukey lambda near 1 (a uniform law) where the noise is not. Where the stuck bits are known
(``stuck_masks``: no code sets, or clears, a bit that codes spread over ``2^(b + 1)`` or
more would), the read noise is fitted by maximum likelihood on the written codes' histogram:
the model's codes (a Tukey-lambda law of scale ``sigma_TL`` about each channel's mean,
rounded) pushed through the same bits (``rawaug.effects.stuck_bit``'s stage) and binned as
the camera wrote them. The loop then adds the bits themselves (``StuckBit``).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy import optimize, special

from ..distributions import tukey_lambda_variance
from .read_noise import ReadNoiseEstimate, sample_indices

BITS = 24  # bits a raw code is checked in
SPREAD = 2  # a bit counts as stuck where the codes' central 98 % spans 2^(b + 1) codes or more


def stuck_masks(codes) -> tuple[int, int]:
    """(low, high): masks of the bits that no code sets (low) or clears (high) while the codes
    spread over enough values that a smooth law would move them."""
    codes = np.asarray(codes, dtype=np.int64).ravel()
    if codes.size == 0:
        return 0, 0
    lo, hi = np.percentile(codes, [1.0, 99.0])
    spread = hi - lo
    any_set = int(np.bitwise_or.reduce(codes))
    all_set = int(np.bitwise_and.reduce(codes))
    low = high = 0
    for b in range(BITS):
        if spread < SPREAD * (1 << b):
            break
        if not any_set >> b & 1:
            low |= 1 << b
        elif all_set >> b & 1:
            high |= 1 << b
    return low, high


def raw_codes_of(frame_dn, black_code, exclude=None, max_samples: int | None = None, seed: int = 0) -> list:
    """Each channel's raw codes (whole DN plus its black code) of a packed (4, h, w) frame, its
    non-finite values (defect lines) and ``exclude`` left out, up to ``max_samples`` a channel."""
    out = []
    for c in range(4):
        keep = np.isfinite(frame_dn[c])
        if exclude is not None:
            keep &= ~np.asarray(exclude[c], dtype=bool)
        values = frame_dn[c][keep]
        idx = sample_indices(values.size, max_samples, seed + c)
        out.append(np.rint((values if idx is None else values[idx]) + float(black_code[c])).astype(np.int64))
    return out


def _written(code, low: int, high: int):
    return (code & ~np.int64(low)) | np.int64(high)


def _code_probabilities(true, mu, s, lam):
    """P(code) of the codes ``true`` for a Tukey-lambda law of scale ``s`` about ``mu``, rounded."""
    return np.diff(special.tklmbda((np.append(true - 0.5, true[-1] + 0.5) - mu) / s, lam))  # at the codes' edges


def fit_through_bits(codes_by_channel, low: int, high: int, start: ReadNoiseEstimate) -> tuple[ReadNoiseEstimate, float]:
    """(read noise, mean slope) of raw codes (a list of 4 arrays, one per channel) written
    through the stuck bits ``low`` / ``high``. The read noise (DN; row noise and all):
    ``lambda`` and ``sigma_TL`` of the least negative log-likelihood of their histograms (a mean
    per channel), from ``start`` (the probability-plot fit); ``sigma_G`` is the fitted law's
    standard deviation. The mean slope: how much a written code's mean moves per DN that the
    signal under it moves (the channels' mean; 1 without stuck bits): near black a stuck bit
    can move half the codes at once, so the row means move more than the row offsets do."""
    chans = [np.asarray(c, dtype=np.int64).ravel() for c in codes_by_channel]
    hists = []
    for c in chans:
        lo = int(c.min())
        hists.append((lo, np.bincount(c - lo)))
    sd = max(float(np.mean([np.std(c) for c in chans])), 0.5)
    reach = int(np.ceil(12 * sd)) + (low | high) + 2  # true codes that can write into the histogram
    grids = [np.arange(lo - reach, lo + counts.size + reach, dtype=np.int64) for lo, counts in hists]

    def nll(theta):
        lam, s = theta[0], np.exp(theta[1])
        total = 0.0
        for (lo, counts), true, mu in zip(hists, grids, theta[2:]):
            p = _code_probabilities(true, mu, s, lam)
            w = _written(true, low, high) - lo
            inside = (w >= 0) & (w < counts.size)
            pw = np.bincount(w[inside], weights=p[inside], minlength=counts.size)
            seen = counts > 0
            total -= float(np.sum(counts[seen] * np.log(np.maximum(pw[seen], 1e-300))))
        return total

    # the written means sit about half the stuck-at-0 bits below the law's (half the stuck-at-1 above)
    means = [float(np.mean(c)) + 0.5 * (low - high) for c in chans]
    shift = (low | high) + 4.0 * sd  # how far the bits and the noise can move a channel's mean
    bounds = [(-0.45, 1.0), (np.log(0.05), np.log(1e4))] + [(m - shift, m + shift) for m in means]
    # the likelihood of a comb is not convex: started from the best points of a coarse grid of
    # shapes and scales (the probability plot's scale takes the comb for noise)
    grid = [(nll(np.array([lam0, np.log(s0), *means])), lam0, s0)
            for lam0 in (-0.2, 0.05, 0.14, 0.4, 0.8) for s0 in np.geomspace(0.3, 2.0 * sd, 12)]
    best = None
    for _, lam0, s0 in sorted(grid)[:3]:
        res = optimize.minimize(nll, np.array([lam0, np.log(s0), *means]), method="L-BFGS-B", bounds=bounds)
        if best is None or res.fun < best.fun:
            best = res
    lam, s = float(best.x[0]), float(np.exp(best.x[1]))
    step = 0.25  # DN: the slope of the written mean, by a central difference
    slopes = []
    for true, mu in zip(grids, best.x[2:]):
        written = _written(true, low, high).astype(np.float64)
        up, down = (float(np.sum(_code_probabilities(true, mu + d, s, lam) * written)) for d in (step, -step))
        slopes.append((up - down) / (2 * step))
    read = ReadNoiseEstimate(lam=lam, sigma_tl=s, sigma_g=s * float(np.sqrt(tukey_lambda_variance(lam))),
                             r2_tukey=start.r2_tukey, r2_gauss=start.r2_gauss, ppcc_grid=start.ppcc_grid,
                             n_samples=int(sum(c.size for c in chans)), std_dn=start.std_dn)
    return read, float(np.mean(slopes))


def through_stuck_bits(codes_by_channel, read: ReadNoiseEstimate, sigma_r: float):
    """(read noise, sigma_r, masks): where the raw codes (4 arrays, one per channel) show stuck
    bits, the read noise fitted through them (``fit_through_bits``), the row noise divided by
    the written mean's slope and its variance taken off the fitted law, and ``{low_mask,
    high_mask}``; else the estimates given and None."""
    low, high = stuck_masks(np.concatenate([np.asarray(c).ravel() for c in codes_by_channel]))
    if not (low or high):
        return read, sigma_r, None
    total, slope = fit_through_bits(codes_by_channel, low, high, read)
    sigma_r = sigma_r / max(slope, 0.2)  # the row means moved by the bits, back to the row offsets under them
    keep = float(np.sqrt(max(1.0 - sigma_r**2 / max(total.sigma_g**2, 1e-12), 0.25)))
    read = dataclasses.replace(total, sigma_tl=total.sigma_tl * keep, sigma_g=total.sigma_g * keep)
    return read, sigma_r, {"low_mask": low, "high_mask": high}
