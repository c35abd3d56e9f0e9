"""Trainings as concurrent child processes sharing one device, for the benchmark drivers
(``ablation/run.py``, ``real_noise/run.py``): at most ``n_jobs`` at once, CPU threads split
between them, side jobs (BM3D) beside them, and everything stopped at a deadline."""
from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

UNFINISHED = 3  # exit status of a driver invocation cut by --time-limit


def run_children(cmd: list[str], jobs: list[tuple[str, list[str], Path]], n_jobs: int, deadline: float | None, start: float,
                 side: list[tuple[str, list[str], Path]] = ()) -> bool:
    """Run ``cmd + extra`` for each job ``(name, extra, log)``, up to ``n_jobs`` at once, and
    every ``side`` job at once beside them (not counted in ``n_jobs``); at ``deadline`` stop
    them all. A failed job stops the others and raises. Returns True when all finished."""
    env = dict(os.environ, OMP_NUM_THREADS=str(max(1, (os.cpu_count() or 1) // max(n_jobs, 1))))
    pending, running, sides = list(jobs), {}, {name for name, _, _ in side}

    def launch(name: str, extra: list[str], log: Path) -> None:
        log.parent.mkdir(parents=True, exist_ok=True)
        with open(log, "a") as f:
            running[name] = (subprocess.Popen(cmd + extra, stdout=f, stderr=subprocess.STDOUT, env=env), log)

    for name, extra, log in side:
        launch(name, extra, log)
    while pending or running:
        if deadline is not None and time.time() >= deadline:
            for proc, _ in running.values():
                proc.terminate()
            for proc, _ in running.values():
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()
            print(f"[{time.time() - start:6.0f} s] time limit: stopped {sorted(running)}; {len(pending)} not started. Run again to resume.")
            return False
        while pending and sum(name not in sides for name in running) < n_jobs:
            launch(*pending.pop(0))
        for name, (proc, log) in list(running.items()):
            if proc.poll() is None:
                continue
            del running[name]
            if proc.returncode:
                for other, _ in running.values():
                    other.terminate()
                raise RuntimeError(f"{name} failed (exit {proc.returncode}); see {log}")
            print(f"[{time.time() - start:6.0f} s] {name} done")
        time.sleep(0.5)
    return True
