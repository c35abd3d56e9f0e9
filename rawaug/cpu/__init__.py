"""The fused noise chain on CPU tensors, compiled with numba (``fused.py``).

Every element draws from ``rawaug.rng``'s counter hash of (stream key, element index), so
results do not depend on the thread count and equal the Triton kernel's:

* Poisson: exact inversion of CDF tables on a lambda grid plus a small remainder, Hormann's
  PTRS above the grid (``poisson.py``);
* Tukey lambda and Gaussian: a tabulated quantile indexed by the tail probability's binary
  exponent and mantissa, linearly interpolated (``quantile_table.py``).
"""
