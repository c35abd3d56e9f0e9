"""Shared fixtures."""
import pytest

from rawaug import cpu


@pytest.fixture(params=["cpu-kernels", "torch-samplers"])
def samplers(request):
    """Run a test with rawaug's numba CPU kernels and again with torch's samplers (the path
    every other device takes), so both stay tested on a machine without a GPU."""
    previous = cpu.use_cpu_kernels(request.param == "cpu-kernels")
    yield request.param
    cpu.use_cpu_kernels(previous)
