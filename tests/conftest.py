"""Shared fixtures."""
import os

import torch

if not torch.cuda.is_available():  # run the Triton kernel on CPU tensors (its interpreter)
    os.environ.setdefault("TRITON_INTERPRET", "1")

import pytest  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

if os.environ.get("PYTEST_XDIST_WORKER"):
    # one xdist worker per core: each worker's BLAS on one thread, or the workers' BLAS threads
    # outnumber the cores (the default run: 4:29 against 5:29 on 2 cores)
    _BLAS_LIMIT = threadpool_limits(limits=1, user_api="blas")

from rawaug.engine import backend  # noqa: E402

try:
    import triton  # noqa: F401

    BACKENDS = ["numba", "triton"]
except ImportError:  # pragma: no cover - triton is a test dependency
    BACKENDS = ["numba"]


if torch.cuda.is_available():
    # no interpreter on a CUDA machine: the tests that run the Triton backend on CPU tensors run
    # the compiled kernel on the GPU instead, their tensors moved there and the result back
    _run_triton = backend._triton

    def _triton_on_gpu(clean, out, values, keys, *rest):
        if clean.device.type != "cpu":
            return _run_triton(clean, out, values, keys, *rest)
        return out.copy_(_run_triton(clean.cuda(), out.cuda(), values.cuda(), keys.cuda(), *rest).cpu())

    backend._triton = _triton_on_gpu


@pytest.fixture(params=BACKENDS)
def samplers(request):
    """Run a test with the numba CPU kernel and again with the Triton kernel (interpreted on
    the CPU where no GPU is, compiled on the GPU where one is), so both backends stay tested
    on a machine without a GPU."""
    previous = backend.set_backend(request.param)
    yield request.param
    backend.set_backend(previous)


# Statistical checks whose Triton run is slow in the interpreter (15-30 s each on a CPU): on a
# machine without a GPU their Triton run is marked slow. The Triton kernel stays checked in the
# default run: ``test_numba_and_triton_draw_the_same_noise`` compares it with the numba kernel,
# whose runs of these checks stay in it, stage for stage.
INTERPRETED_SLOW = {"test_full_model_pixel_and_row_mean_variance_match_analytic", "test_colour_bias_is_added_on_request_not_by_default",
                    "test_poisson_shot_noise_is_poisson_in_electrons", "test_defect_line_stage_draws_its_lines",
                    "test_each_tap_has_its_own_row_offsets"}  # 125 s in the interpreter (32 frames)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    if torch.cuda.is_available():
        return
    for item in items:
        params = getattr(getattr(item, "callspec", None), "params", {})
        if item.originalname in INTERPRETED_SLOW and "triton" in params.values():
            item.add_marker(pytest.mark.slow)
