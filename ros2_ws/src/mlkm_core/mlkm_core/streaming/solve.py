"""A window solve as a pure, picklable step, so it can run beside the stream.

``StreamTracker`` snapshots the problem of a boundary (``WindowProblem``: plain arrays, the
method's name and settings), ``solve`` turns it into a ``WindowSolution`` anywhere (in the
caller, a thread, another process) and the tracker applies the solution at its boundary.
``solve`` is a function of the problem alone, so where and when it runs never changes the
committed association.

Calibration is the costliest part of a solve (docs/benchmarks.md#stream-tracker-settings),
and traffic changes slowly: a window of a method that calibrates its motion model
on its input (``Associator.calibrates``) either calibrates (and returns the model as a
``CarriedModel``) or is given the model of the last calibrating window, carried over to its
own detections. A model that learnt the order of passage within lanes (a queue) is bound to
the detections it was learnt on and is not carried: the next window calibrates again. The
count-curve profile of a gap's extra time is dropped from a carried model (its mean stays);
the traffic's slowness over time is taken again from each window's own detections.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from mlkm_core.associators import make_associator
from mlkm_core.associators.base import AssociatorConfig, canonical_order
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.model.catalogue import bind_cues
from mlkm_core.model.motion import MotionParams
from mlkm_core.model.traffic import estimate_traffic
from mlkm_core.streaming.motion import MIN_CALIBRATION, calibrate_on
from mlkm_core.streaming.window import solve_window
from mlkm_core.types import Detections, Layout


@dataclass(frozen=True)
class CarriedModel:
    """A method's calibrated motion model, free of the detections it was calibrated on."""

    params: MotionParams  # cues and traffic None
    cues: dict[str, Any] | None  # the cues' parameters by name (None: no cue)
    reusable: bool  # False: a cue holds what it learnt from its own detections
    traffic: bool = False  # the model follows the traffic's slowness, taken from each window

    @staticmethod
    def of(params: MotionParams) -> CarriedModel:
        """The model without what ties it to its detections: the cues' own state, the
        gaps' count-curve profiles (their times; each gap keeps its mean extra time) and the
        traffic's slowness over time (each window takes its own from its detections)."""
        cues = params.cues
        if params.delay is not None and params.delay.profiles:
            params = replace(params, delay=replace(params.delay, profiles=()))
        return CarriedModel(
            replace(params, cues=None, traffic=None),
            None if cues is None else cues.carried(),
            cues is None or cues.reusable,
            params.traffic is not None,
        )

    def bind(self, layout: Layout, d: Detections) -> MotionParams:
        """The model for the detections ``d`` (in the order the associator will use)."""
        params = self.params
        if self.traffic:
            params = replace(params, traffic=estimate_traffic(layout, d, min_z=0.0))
        if self.cues is None:
            return params
        return replace(params, cues=bind_cues(layout, d, self.cues))


@dataclass(frozen=True)
class WindowProblem:
    """What one window solve needs."""

    method: str  # registered associator
    config: AssociatorConfig
    layout: Layout
    detections: Detections  # context, anchors, then the window (canonical order each)
    calibration: np.ndarray | None  # (n, 3) rows (sensor, stamp, speed): recalibrate on them
    # a method that calibrates: None = calibrate on the detections (the solution returns the
    # model), else the model to carry over
    model: CarriedModel | None = None
    # what the method decides once per stream, from the windows solved so far: their
    # evidence added up (``Associator.settled``; None: none yet)
    evidence: tuple[float, float] | None = None
    # (entry rate, exit rate) per station from the stream's ended tracks (``entries``; None:
    # none estimated): a window's own tracks begin and end at its edges
    rates: tuple[np.ndarray | None, np.ndarray | None] | None = None
    # the window is the whole input (a flush before any commit): every vehicle's passages
    # are in it, as in batch (``estimate_params(whole_passages=True)``)
    whole: bool = False


@dataclass(frozen=True)
class WindowSolution:
    labels: np.ndarray  # cluster of each row of the problem, -1 = alone
    degraded: int  # degraded-result warnings of the method
    failed: bool  # the method could not associate the window (generic assignment instead)
    params: MotionParams | None  # the recalibrated motion model (None: keep the current one)
    model: CarriedModel | None = None  # the method's model, when this solve calibrated it
    evidence: tuple[float, float] | None = None  # this window's (``Associator.settled``)


#: most evidence weight the stream keeps (links, for ``multiframe``): about 20 windows of a
#: busy road; beyond it the older evidence is scaled down, so that a change of traffic (free
#: flow into stop-and-go) turns the decision within as many windows
EVIDENCE_WEIGHT = 20_000.0


def add_evidence(
    kept: tuple[float, float] | None, new: tuple[float, float], share: float = 1.0
) -> tuple[float, float]:
    """``kept`` (sum, weight) plus ``share`` of a window's evidence ``new``, scaled to at
    most ``EVIDENCE_WEIGHT``. The tracker adds each window for the share of its rows it
    commits: every detection is committed once, so overlapping windows count a link about
    once, and a stream that commits nothing before its flush decides as batch does, on the
    whole input."""
    total, weight = new[0] * share, new[1] * share
    if kept is not None:
        total, weight = total + kept[0], weight + kept[1]
    if weight > EVIDENCE_WEIGHT:
        total, weight = total * EVIDENCE_WEIGHT / weight, EVIDENCE_WEIGHT
    return total, weight


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
    layout, d = problem.layout, problem.detections
    motion, model = None, None
    if associator.calibrates and len(d):
        # the associator's own canonical order, in which its model is bound
        ordered = d.subset(canonical_order(d))
        if problem.model is None:
            try:
                cfg = problem.config
                openings = MotionParams.road_openings(layout.positions, cfg.entries, cfg.exits)
                motion = estimate_params(layout, ordered, openings, whole_passages=problem.whole)
            except ValueError:
                motion = None  # solve_window replaces the method for this window
            # a model calibrated on too few detections is used for this window only
            if motion is not None and len(ordered) >= MIN_CALIBRATION:
                model = CarriedModel.of(motion)
        else:
            motion = problem.model.bind(layout, ordered)
    evidence = None
    if motion is not None and problem.rates is not None and not problem.whole:
        motion = replace(motion, entry_rate=problem.rates[0], exit_rate=problem.rates[1])
    if motion is not None:
        motion, evidence = associator.settled(layout, ordered, motion, problem.evidence)
    labels, degraded, failed = solve_window(associator, layout, d, motion)
    return WindowSolution(labels, degraded, failed, params, model, evidence)


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
