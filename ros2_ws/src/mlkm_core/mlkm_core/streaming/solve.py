"""A window solve as a pure, picklable step, so it can run beside the stream.

``StreamTracker`` snapshots the problem of a boundary (``WindowProblem``: plain arrays, the
method's name and settings), ``solve`` turns it into a ``WindowSolution`` anywhere (in the
caller, a thread, another process) and the tracker applies the solution at its boundary.
``solve`` is a function of the problem alone, so where and when it runs never changes the
committed association.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from mlkm_core.associators import make_associator
from mlkm_core.associators.base import AssociatorConfig
from mlkm_core.associators.motion import MotionParams
from mlkm_core.streaming.motion import calibrate_on
from mlkm_core.streaming.window import solve_window
from mlkm_core.types import Detections, Layout


@dataclass(frozen=True)
class WindowProblem:
    """What one window solve needs."""

    method: str  # registered associator
    config: AssociatorConfig
    layout: Layout
    detections: Detections  # context, anchors, then the window (canonical order each)
    calibration: np.ndarray | None  # (n, 3) rows (sensor, stamp, speed): recalibrate on them


@dataclass(frozen=True)
class WindowSolution:
    labels: np.ndarray  # cluster of each row of the problem, -1 = alone
    degraded: int  # degraded-result warnings of the method
    failed: bool  # the method could not associate the window (generic assignment instead)
    params: MotionParams | None  # the recalibrated motion model (None: keep the current one)


_ASSOCIATORS: dict[tuple[str, AssociatorConfig], Any] = {}


def solve(problem: WindowProblem) -> WindowSolution:
    """Solve one window (pure: the same problem always gives the same solution)."""
    key = (problem.method, problem.config)
    associator = _ASSOCIATORS.get(key)
    if associator is None:
        associator = _ASSOCIATORS[key] = make_associator(problem.method, problem.config)
    params = None
    if problem.calibration is not None:
        params = calibrate_on(problem.layout, problem.calibration)
    labels, degraded, failed = solve_window(associator, problem.layout, problem.detections)
    return WindowSolution(labels, degraded, failed, params)


class InlineExecutor:
    """Runs each submitted solve at once in the caller (``concurrent.futures`` shape)."""

    def submit(self, fn, *args):
        from concurrent.futures import Future

        future: Future = Future()
        try:
            future.set_result(fn(*args))
        except Exception as exc:  # noqa: BLE001 - handed to whoever reads the result
            future.set_exception(exc)
        return future
