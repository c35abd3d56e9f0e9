"""The Triton kernel compiles for real GPUs, on a machine without one.

``TRITON_INTERPRET=1`` (how the kernel runs in CI) executes it as Python and accepts code
that the compiler rejects, e.g. a module global that is not constexpr. This compiles the
kernel to cubins with Triton's own ptxas. The default run compiles every stage for Hopper
(sm_90) in two kernels of alternate stages (12 s; one kernel with all of them takes ~55 s:
Triton's coalescing pass grows faster than the kernel); ``-m slow`` compiles the kernel with
every stage for Hopper and for Ampere (sm_80), and every branch of its stage switches."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("triton")

def compile_targets(targets):
    """Compile ``targets`` (one process per list of them, at once) and check every cubin."""
    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    script = str(Path(__file__).with_name("compile_kernel.py"))
    procs = [subprocess.Popen([sys.executable, script, *part], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
             for part in targets]
    result = {}
    for proc in procs:
        out, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err[-3000:]
        result.update(json.loads(out.strip().splitlines()[-1]))
    assert sorted(result) == sorted(t for part in targets for t in part)
    for target, outcome in result.items():
        assert isinstance(outcome, int) and outcome > 1000, f"{target}: {outcome}"


def test_every_stage_compiles_for_the_gpu():
    compile_targets([["even@90", "odd@90"]])  # every stage, for Hopper, in two kernels (one process)


@pytest.mark.slow
def test_every_branch_compiles_for_hopper_and_ampere():
    compile_targets([["all@90", "G@90"], ["P,G*@90", "all@80"]])  # all stages at once; the switches' other branches; Ampere
