"""The closed loop: find where model and measurement disagree, trace it to a missing
physical effect, add the effect, and report the error before and after.

* ``statistics``: the battery of frame statistics;
* ``diagnose``: measured stack vs repeated syntheses -> ranked residuals;
* ``registry``: candidate effects (statistic -> effect -> estimator);
* ``frames_loop``: the loop on frame stacks;
* ``parameters``: the loop on per-ISO parameter tables (regime change, noise floor) and on
  per-frame fit tables (frame-to-frame black-level error);
* ``report``: report.json and report.md; ``command``: ``rawaug loop``.
"""
from .diagnose import FrameStack, Residual, battery_error, diagnose, synthesize  # noqa: F401
from .frames_loop import LoopResult, Step, run_frame_loop  # noqa: F401
from ..statistics import STATISTICS, frame_statistics  # noqa: F401
