"""What the stream lacks against batch on the NGSIM loops: the travel-time spread per gap.

``python -m mlkm_experiments.stream_warmup [--stations 5] [--road closed] [--placements 3]``
(from the repository root) runs, on the time-and-speed loops of ``mlkm bench --only real``,
batch ``multiframe``, the stream tracker with the live node's settings, and the same stream
whose every window is given the gap delays (``MotionParams.delay``: each gap's extra travel
time and its spread, ``delays.estimate_gap_spread``) that batch fits on the whole recording,
the rest of each window's model fitted on the window as usual. It prints the accuracy of the
three per placement. Where the third closes most of the stream's gap to batch, that gap is the
spread the windows fit on the traffic seen so far: early in a recording the residuals of the
travel time are narrower than later on and heavy-tailed, and the true links in their tails are
priced out. The recording (part A: about 4 minutes) is the stream's warm-up throughout.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from dataclasses import replace

import numpy as np

from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.associators.base import canonical_order
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.metrics import accuracy
from mlkm_core.model.gap_delays import GapDelays
from mlkm_core.model.motion import MotionParams
from mlkm_core.streaming import StreamConfig
from mlkm_core.streaming.motion import MIN_CALIBRATION
from mlkm_core.streaming.solve import (
    CarriedModel,
    InlineExecutor,
    WindowProblem,
    WindowSolution,
    solve,
)
from mlkm_core.trajectories import read_trajectories
from mlkm_core.types import Dataset, Detections, Layout

from .bench import real
from .bench.common import BEST, time_speed_only
from .bench.stream_lag import stream_labels


class GivenDelays(InlineExecutor):
    """Solves each window in the caller as ``solve`` does, but a window that calibrates its
    model fits it on its detections with ``delay`` in place of the gap delays it would fit,
    and hands that model on to the windows that carry it."""

    def __init__(self, delay: GapDelays | None) -> None:
        self.delay = delay

    def submit(self, fn, *args):
        return super().submit(self._solve, *args)

    def _solve(self, problem: WindowProblem) -> WindowSolution:
        layout, d, cfg = problem.layout, problem.detections, problem.config
        if problem.model is not None or not len(d):
            return solve(problem)  # a carried model holds ``delay`` already
        if not make_associator(problem.method, cfg).calibrates:
            return solve(problem)
        try:
            own = fitted(layout, d, cfg, whole_passages=False)
        except ValueError:
            return solve(problem)  # the solve replaces the method for this window
        model = CarriedModel.of(replace(own, delay=self.delay))
        solution = solve(replace(problem, model=model))
        return replace(solution, model=model if len(d) >= MIN_CALIBRATION else None)


def fitted(
    layout: Layout, d: Detections, cfg: AssociatorConfig, whole_passages: bool = True
) -> MotionParams:
    """The model a calibrating method fits on ``d`` (``calibration.estimate_params``)."""
    openings = MotionParams.road_openings(layout.positions, cfg.entries, cfg.exits)
    return estimate_params(layout, d.subset(canonical_order(d)), openings, whole_passages)


def stream_accuracy(ds: Dataset, executor=None) -> float:
    """Accuracy of the stream tracker (``StreamConfig`` defaults, ``multiframe``) on ``ds``,
    pushed in stamp order and flushed."""
    labels = stream_labels(ds, StreamConfig.lag, BEST, executor)
    return accuracy(labels, ds.detections.target).accuracy


def whole_recording_delay(ds: Dataset) -> GapDelays | None:
    """The gap delays batch fits on the whole of ``ds``."""
    return fitted(ds.layout, ds.detections, AssociatorConfig()).delay


def compare(ds: Dataset) -> tuple[float, float, float]:
    """(batch ``multiframe``, stream, stream with the whole recording's gap delays)."""
    batch = make_associator('multiframe', AssociatorConfig()).associate(
        ds.layout, ds.detections, ds.n_targets
    )
    given = GivenDelays(whole_recording_delay(ds))
    return (
        accuracy(batch, ds.detections.target).accuracy,
        stream_accuracy(ds),
        stream_accuracy(ds, given),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m mlkm_experiments.stream_warmup')
    parser.add_argument('--stations', type=int, default=5, choices=real.STATIONS)
    parser.add_argument('--road', default='closed', choices=real.VARIANTS_ROAD)
    parser.add_argument('--placements', type=int, default=3, help='datasets (1..N)')
    args = parser.parse_args(argv)
    warnings.simplefilter('ignore')
    traj = read_trajectories(real.DATA)
    seeds = list(range(1, args.placements + 1))
    print('placement first_m batch_% stream_% stream_whole_gap_delays_%')
    rows = []
    for seed, ds in zip(seeds, real.datasets(traj, args.stations, args.road, seeds), strict=True):
        rows.append(compare(time_speed_only(ds)))
        cells = ' '.join(f'{100 * a:.2f}' for a in rows[-1])
        print(f'{seed} {real.placement(seed):.1f} {cells}', flush=True)
    means = ' '.join(f'{100 * a:.2f}' for a in np.mean(rows, axis=0))
    print(f'mean - {means}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
