"""Settings and results of the streaming tracker (see ``mlkm_core.streaming``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mlkm_core.associators.base import AssociatorConfig

#: Track status, the values of ``road_sensor_msgs/Track.STATUS_*``.
TENTATIVE, CONFIRMED, FINAL = 0, 1, 2


@dataclass(frozen=True)
class StreamConfig:
    """Settings of :class:`~mlkm_core.streaming.StreamTracker`; every time is stamp time."""

    method: str = 'multiframe'  # any registered associator (available_methods())
    # [s] a link may be revised until the newest stamp is `lag` past the detection's stamp,
    # then it is committed for good. It must exceed the travel time between consecutive
    # stations (else a vehicle's first detection is committed alone, as a false alarm). A
    # longer lag leaves more evidence to each revision and delays every commit by as much; the
    # default is the shortest lag whose committed accuracy stays within the benchmark's
    # tolerance of batch (`mlkm bench --only stream`; figures in docs/benchmarks.md).
    lag: float = 15.0
    # [-] the lag grows (never shrinks) to this many times the 95th percentile of the travel
    # times to the next station that the measured speeds predict (gap / speed): in slow
    # traffic (a queue, closely spaced stations) a vehicle takes longer than ``lag`` from one
    # station to the next, and its link must stay revisable until the next station has seen
    # it; the speeds are the data's own, so the lag fits the traffic of the road it runs on
    # (docs/streaming.md). 0 = the lag stays ``lag``
    lag_factor: float = 2.0
    # [s] the window is re-solved at every multiple of this; longer windows calibrate the
    # methods' model on more tracks, and fewer solves cost less CPU (docs/benchmarks.md)
    solve_interval: float = 10.0
    # [s] pushes may arrive this much out of stamp order without changing any committed
    # label: a window is solved once the newest stamp is this far past its boundary
    reorder_tolerance: float = 1.0
    confirm_count: int = 2  # detections that make a track CONFIRMED
    anchor_depth: int = 3  # committed detections per open track given to each window solve
    # detections of the most recently ended tracks (of 3 or more) added to the calibrating
    # window solves of assignment, multiframe and mlkm_robust, which calibrate their motion
    # model on their input: on sparse traffic a window alone holds too few tracks for it, and
    # the context brings the stream's accuracy to that of batch (docs/benchmarks.md); 0 = none
    context_size: int = 300
    calibration_size: int = 1000  # committed detections kept for the K-means methods' model
    # recalibrate the motion model every this many solves; in between, the windows of the
    # calibrating methods get the last model carried over, since a calibration is a large
    # share of a multiframe window solve and the model changes slowly with the traffic (its
    # effect on accuracy: docs/benchmarks.md); a model estimated on fewer than context_size
    # rows is not carried (the first windows of a road filling up calibrate each time)
    calibration_every: int = 6
    # the associators' settings, with their defaults (``AssociatorConfig``)
    segment_size: int = AssociatorConfig.segment_size  # K of the MLKM methods
    seed: int = AssociatorConfig.seed  # random_state of the K-means methods
    # multiframe: candidates scored per window solve and start
    search_budget: int = AssociatorConfig.search_budget
    # [-] once more detections than this wait for their commit (window solves beside the
    # stream that cannot keep up), the due boundaries are committed on the immediate links
    # without a solve and the solve in flight is dropped (``StreamTracker.overloaded``);
    # 0 = no bound. Solved inline, the backlog stays near a lag of traffic.
    max_uncommitted: int = 0

    def __post_init__(self) -> None:
        from mlkm_core.associators.base import METHODS

        METHODS.get(self.method)  # a ValueError naming the choices if unknown
        checks = (
            (math.isfinite(self.lag) and self.lag > 0, 'lag must be a finite number > 0'),
            (
                math.isfinite(self.lag_factor) and self.lag_factor >= 0,
                'lag_factor must be a finite number >= 0',
            ),
            (
                math.isfinite(self.solve_interval) and self.solve_interval > 0,
                'solve_interval must be a finite number > 0',
            ),
            (
                math.isfinite(self.reorder_tolerance) and self.reorder_tolerance >= 0,
                'reorder_tolerance must be a finite number >= 0',
            ),
            (self.confirm_count >= 1, 'confirm_count must be >= 1'),
            (self.anchor_depth >= 1, 'anchor_depth must be >= 1'),
            (self.context_size >= 0, 'context_size must be >= 0'),
            (self.calibration_size >= 0, 'calibration_size must be >= 0'),
            (self.calibration_every >= 1, 'calibration_every must be >= 1'),
            (self.segment_size >= 1, 'segment_size must be >= 1'),
            (0 <= self.seed < 2**32, 'seed must be in [0, 2^32)'),
            (self.search_budget >= 0, 'search_budget must be >= 0'),
            (self.max_uncommitted >= 0, 'max_uncommitted must be >= 0'),
        )
        for ok, message in checks:
            if not ok:
                raise ValueError(f'{message}, got {self!r}')

    def associator_config(self) -> AssociatorConfig:
        return AssociatorConfig(
            segment_size=self.segment_size, seed=self.seed, search_budget=self.search_budget
        )


@dataclass(frozen=True)
class TrackUpdate:
    """A track whose membership or status changed."""

    track_id: int  # stable for the tracker's lifetime, never reused
    status: int  # TENTATIVE / CONFIRMED / FINAL
    keys: np.ndarray  # int64 caller keys of ALL the track's detections, in stamp order


def _no_keys() -> np.ndarray:
    return np.zeros(0, np.int64)


@dataclass(frozen=True)
class StreamUpdate:
    """What one ``push`` or ``flush`` changed."""

    tracks: list[TrackUpdate] = field(default_factory=list)  # changed membership or status
    unassigned: np.ndarray = field(default_factory=_no_keys)  # keys made unassigned (-1)
    committed_until: float = -math.inf  # [s] every link of an older detection is committed
    committed: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
