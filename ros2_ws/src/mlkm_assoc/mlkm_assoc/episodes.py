"""The association node's settings, one episode's buffers, and the work handed to the solver.

Plain data for :mod:`mlkm_assoc.assembly` (which decides what goes where) and
:mod:`mlkm_assoc.solver` (which associates it). ROS-free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlkm_core.associators.base import AssociatorConfig
from mlkm_core.bounds import Bounds
from mlkm_core.types import UNKNOWN_LANE, Layout, segments

_DEFAULT_BOUNDS = Bounds()
_ASSOCIATOR = AssociatorConfig()


@dataclass(frozen=True)
class AssociationConfig:
    """The association node's settings (from its parameters)."""

    method: str = 'mlkm'
    segment_size: int = _ASSOCIATOR.segment_size
    seed: int = _ASSOCIATOR.seed
    completion_timeout: float = 5.0  # [s]
    episode_timeout: float = 60.0  # an open episode without any input is closed after [s]
    max_buffered: int = 5_000_000  # held detections (before layout / episode) [-]
    max_finished_episodes: int = 100  # finished episodes remembered for late detections [-]
    min_speed: float = _DEFAULT_BOUNDS.min_speed  # [m/s]
    max_speed: float = _DEFAULT_BOUNDS.max_speed  # [m/s]
    min_stamp: float = _DEFAULT_BOUNDS.min_stamp  # [s]
    max_stamp: float = _DEFAULT_BOUNDS.max_stamp  # [s]
    min_length: float = _DEFAULT_BOUNDS.min_length  # [m]
    max_length: float = _DEFAULT_BOUNDS.max_length  # [m]
    # on- and off-ramp positions [m] of the current layout (its entry_positions and
    # exit_positions, not parameters): an open road for the associators
    entries: tuple[float, ...] = ()
    exits: tuple[float, ...] = ()

    def associator_config(self) -> AssociatorConfig:
        return AssociatorConfig(
            segment_size=self.segment_size, seed=self.seed, entries=self.entries, exits=self.exits
        )

    def bounds(self) -> Bounds:
        """The physical bounds of a detection; raises ValueError when they contradict."""
        return Bounds(
            self.min_speed,
            self.max_speed,
            self.min_stamp,
            self.max_stamp,
            self.min_length,
            self.max_length,
        )


@dataclass(frozen=True)
class Part:
    """Detections of one segment, sorted by (sensor index, stamp, lane)."""

    sensor_index: np.ndarray  # int64
    stamps_ns: np.ndarray  # int64
    velocities: np.ndarray  # float64
    lanes: np.ndarray | None = None  # int64, -1 = unknown (default: all unknown)
    lengths: np.ndarray | None = None  # float64 [m], NaN = unknown (default: all unknown)

    def __post_init__(self) -> None:
        n = np.asarray(self.stamps_ns).size
        if self.lanes is None:
            object.__setattr__(self, 'lanes', np.full(n, UNKNOWN_LANE, np.int64))
        if self.lengths is None:
            object.__setattr__(self, 'lengths', np.full(n, np.nan))


@dataclass(frozen=True)
class Job:
    """Work for the solver. kind: 'segment' (feed ``parts[0]``), 'final' (publish the
    association so far as final) or 'rerun' (associate ``parts`` from scratch, final)."""

    kind: str
    episode_id: int
    layout: Layout
    n_targets: int
    method: str
    associator_config: AssociatorConfig
    segments_total: int
    parts: tuple[Part, ...]
    completed_at: float  # monotonic time the segment became complete
    forced: bool = False  # completed by a timeout rather than by the counts
    missing: int = 0  # with a final: detections ENDED announced that never arrived [-]


class Episode:
    """Buffers and progress of one episode."""

    def __init__(
        self,
        episode_id: int,
        num_targets: int,
        start_ns: int,
        end_ns: int,
        layout: Layout,
        config: AssociationConfig,
        now: float,
    ) -> None:
        n = layout.n_sensors
        self.id = episode_id
        self.num_targets = num_targets
        self.start_ns = start_ns
        self.end_ns = end_ns
        self.layout = layout
        self.method = config.method
        self.associator_config = config.associator_config()
        self.segments = [seg.tolist() for seg in segments(n, config.segment_size)]
        self.seg_of = [0] * n
        for e, seg in enumerate(self.segments):
            for s in seg:
                self.seg_of[s] = e
        self.stamps: list[list[int]] = [[] for _ in range(n)]
        self.vels: list[list[float]] = [[] for _ in range(n)]
        self.lanes: list[list[int]] = [[] for _ in range(n)]
        self.lengths: list[list[float]] = [[] for _ in range(n)]
        # per sensor: the keys of its detections, (stamp, lane) or (stamp, -1, velocity)
        self.seen: list[set[tuple]] = [set() for _ in range(n)]
        self.rejected = [0] * n  # messages of this episode refused, per sensor index
        self.accepted = 0
        self.ended: list[int] | None = None  # ENDED counts per sensor index
        self.next_segment = 0
        self.dirty = False  # a detection arrived for a segment already solved
        self.finalized = False
        self.last_activity = now  # monotonic time of its latest input [s]

    def set_ended(self, counts: dict[int, int], index: dict[int, int]) -> None:
        self.ended = [0] * len(self.seg_of)
        for sensor_id, count in counts.items():
            s = index.get(sensor_id)
            if s is not None:
                self.ended[s] = count

    def sensor_done(self, s: int) -> bool:
        """Only accepted detections count: a refused message may not have been announced."""
        if self.ended is not None:
            return len(self.stamps[s]) >= self.ended[s]
        return len(self.stamps[s]) >= self.num_targets

    def missing(self) -> int:
        """Detections ENDED announced that neither were accepted nor refused here."""
        if self.ended is None:
            return 0
        return sum(
            max(0, want - len(got) - bad)
            for want, got, bad in zip(self.ended, self.stamps, self.rejected)
        )

    def buffered(self) -> int:
        return sum(len(x) for x in self.stamps)

    def free(self) -> None:
        """Drop the buffers; the window stays so that late detections are recognised."""
        self.stamps, self.vels, self.seen = [], [], []
        self.lanes, self.lengths = [], []

    def part(self, sensors: list[int]) -> Part:
        idx, ns, vel, lane, size = [], [], [], [], []
        for s in sensors:
            st, vl, ln, sz = self.stamps[s], self.vels[s], self.lanes[s], self.lengths[s]
            order = sorted(range(len(st)), key=lambda i: (st[i], ln[i]))
            idx.extend([s] * len(st))
            ns.extend(st[i] for i in order)
            vel.extend(vl[i] for i in order)
            lane.extend(ln[i] for i in order)
            size.extend(sz[i] for i in order)
        return Part(
            np.asarray(idx, dtype=np.int64),
            np.asarray(ns, dtype=np.int64),
            np.asarray(vel, dtype=float),
            np.asarray(lane, dtype=np.int64),
            np.asarray(size, dtype=float),
        )

    def job(self, kind: str, parts: tuple[Part, ...], now: float, forced: bool) -> Job:
        """The solver's work of ``kind`` ('segment', 'rerun' or 'final') on ``parts``."""
        return Job(
            kind=kind,
            episode_id=self.id,
            layout=self.layout,
            n_targets=self.num_targets,
            method=self.method,
            associator_config=self.associator_config,
            segments_total=len(self.segments),
            parts=parts,
            completed_at=now,
            forced=forced,
            missing=self.missing() if kind != 'segment' else 0,
        )
