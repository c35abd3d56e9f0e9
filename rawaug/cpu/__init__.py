"""Counter-based noise samplers for CPU tensors, compiled with numba.

On the GPU, torch's own samplers are fast; on the CPU they are not (``torch.poisson`` and
``torch.rand`` run single-threaded at 10-80 ns per element). These kernels draw every
element from a hash of (key, element index): results do not depend on the thread count,
and replaying a key replays the noise bit-exactly.

* Poisson: exact inversion of CDF tables on a lambda grid plus a small remainder, Hormann's
  PTRS above the grid (``poisson.py``);
* Tukey lambda and Gaussian: a tabulated quantile indexed by the tail probability's
  binary exponent and mantissa, linearly interpolated (``quantile_table.py``);
* uniform (quantization) noise (``uniform.py``).

Set ``RAWAUG_CPU_KERNELS=0`` (or call ``use_cpu_kernels(False)``) to use torch's samplers
on the CPU too, as on every other device.
"""
from __future__ import annotations

import os

import torch

try:  # numba is a dependency, but keep rawaug importable where it cannot be installed
    import numba  # noqa: F401

    AVAILABLE = True
except ImportError:  # pragma: no cover - exercised only without numba
    AVAILABLE = False

_enabled = os.environ.get("RAWAUG_CPU_KERNELS", "1") != "0"


def use_cpu_kernels(flag: bool) -> bool:
    """Switch the CPU kernels on or off; returns the previous setting."""
    global _enabled
    previous, _enabled = _enabled, bool(flag)
    return previous


def handles(t: torch.Tensor) -> bool:
    """Whether the CPU kernels draw the noise of this tensor."""
    return (_enabled and AVAILABLE and t.device.type == "cpu" and t.dtype in (torch.float32, torch.float64)
            and not t.requires_grad)
