"""Shared fixtures."""
import os

import torch

if not torch.cuda.is_available():  # run the Triton kernel on CPU tensors (its interpreter)
    os.environ.setdefault("TRITON_INTERPRET", "1")

import pytest  # noqa: E402

from rawaug.engine import backend  # noqa: E402

try:
    import triton  # noqa: F401

    BACKENDS = ["numba", "triton"]
except ImportError:  # pragma: no cover - triton is a test dependency
    BACKENDS = ["numba"]


@pytest.fixture(params=BACKENDS)
def samplers(request):
    """Run a test with the numba CPU kernel and again with the Triton kernel (interpreted on
    the CPU where no GPU is), so both backends stay tested on a machine without a GPU."""
    previous = backend.set_backend(request.param)
    yield request.param
    backend.set_backend(previous)
