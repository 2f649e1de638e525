"""Live assembly of detections into episodes and road segments (ROS-free).

The association node feeds every received detection and episode message in here; this module
decides, cheaply per message, which episode and segment a detection belongs to, whether it is
valid, and when a segment is complete. Complete segments come out as :class:`Job` objects,
strictly in segment order per episode, for the solver (:mod:`mlkm_assoc.solver`).

Policies (README "Association node"):

* Episode assignment: a detection belongs to the episode whose [start, end] window (from
  EpisodeInfo) holds its stamp. Detections whose episode is not known yet are held (topics
  are not ordered against each other) and placed when the EpisodeInfo arrives; held longer
  than ``completion_timeout`` or older than a later known episode: rejected
  ``outside_episode``.
* Completion: a sensor is done for an episode when it has ``num_targets`` valid detections
  (the paper's setting, before the episode has ended) or, once ENDED has arrived, when as many
  messages arrived from it as ENDED counts. A segment is complete when all its sensors are
  done; segments go to the solver in order (segment e+1 waits for e). The final association
  is published when every segment went out and ENDED's counts are met, or
  ``completion_timeout`` seconds after the last activity once the episode ended (what is
  there is then associated; counted as ``completion_timeout``).
* A detection that arrives for a segment already solved (clutter: a sensor with more
  detections than targets; or a stamp out of order) is kept; the episode's final association
  is then recomputed from scratch over every detection, so the final tracks hold it.
* Rejected with a reason: NaN / infinite / zero / negative velocity, unknown sensor id,
  position not matching the layout, duplicate (same sensor and stamp), stamp outside every
  episode window, a detection for an episode already finalised, buffer overflow.
* Handled (kept) and counted: detection before the layout is known (held, checked when the
  layout arrives), stamp out of order on its sensor, more detections than targets at one
  sensor (the associator decides; extras may end up unassigned), late for its segment.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mlkm_core.associators.base import AssociatorConfig
from mlkm_core.types import Layout, segments

#: Reasons a detection is rejected (not associated).
REJECT_REASONS = (
    'nan_velocity',
    'inf_velocity',
    'zero_velocity',
    'negative_velocity',
    'unknown_sensor',
    'position_mismatch',
    'duplicate',
    'outside_episode',
    'after_episode_final',
    'buffer_full',
)
#: Irregular inputs that are kept and associated, counted by reason.
HANDLED_REASONS = (
    'before_layout',
    'out_of_order',
    'excess_at_sensor',
    'late_for_segment',
    'completion_timeout',
)
#: Tolerance between a detection's position and its sensor's layout position [m].
POSITION_TOLERANCE = 1e-3


@dataclass(frozen=True)
class AssociationConfig:
    """The association node's settings (from its parameters)."""

    method: str = 'mlkm'
    segment_size: int = 5
    seed: int = 0
    completion_timeout: float = 5.0  # [s]
    max_buffered: int = 5_000_000  # held detections (before layout / episode) [-]

    def associator_config(self) -> AssociatorConfig:
        return AssociatorConfig(segment_size=self.segment_size, seed=self.seed)


@dataclass(frozen=True)
class Part:
    """Detections of one segment, sorted by (sensor index, stamp)."""

    sensor_index: np.ndarray  # int64
    stamps_ns: np.ndarray  # int64
    velocities: np.ndarray  # float64


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
    segment: int  # index of the segment fed ('segment'), else the number of segments
    segments_total: int
    parts: tuple[Part, ...]
    completed_at: float  # monotonic time the segment became complete
    forced: bool = False  # completed by the timeout rather than by the counts


class _Episode:
    """Buffers and progress of one episode."""

    def __init__(
        self,
        episode_id: int,
        num_targets: int,
        start_ns: int,
        end_ns: int,
        layout: Layout,
        config: AssociationConfig,
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
        self.seen: list[set[int]] = [set() for _ in range(n)]
        self.received = [0] * n  # messages attributed to each sensor (valid or not)
        self.ended: list[int] | None = None  # ENDED counts per sensor index
        self.next_segment = 0
        self.dirty = False
        self.finalized = False
        self.last_activity = 0.0

    def sensor_done(self, s: int) -> bool:
        if self.ended is not None:
            return self.received[s] >= self.ended[s]
        return len(self.stamps[s]) >= self.num_targets

    def buffered(self) -> int:
        return sum(len(x) for x in self.stamps)

    def part(self, sensors: list[int]) -> Part:
        idx, ns, vel = [], [], []
        for s in sensors:
            st, vl = self.stamps[s], self.vels[s]
            order = sorted(range(len(st)), key=st.__getitem__)
            idx.extend([s] * len(st))
            ns.extend(st[i] for i in order)
            vel.extend(vl[i] for i in order)
        return Part(
            np.asarray(idx, dtype=np.int64),
            np.asarray(ns, dtype=np.int64),
            np.asarray(vel, dtype=float),
        )


Raw = tuple[int, int, float, float, float]  # sensor id, stamp [ns], position, velocity, t_rx


class Assembler:
    """Episode and segment bookkeeping; emits :class:`Job` s through ``submit``."""

    def __init__(
        self,
        config: AssociationConfig,
        submit: Callable[[Job], None],
        on_reject: Callable[[str, str], None] | None = None,
    ) -> None:
        self.config = config
        self._submit = submit
        self._on_reject = on_reject
        self.layout: Layout | None = None
        self._index: dict[int, int] = {}
        self._positions: list[float] = []
        self._last_stamp: list[int] = []
        self._infos: dict[int, tuple[int, int, int]] = {}  # id -> (num_targets, start, end)
        self._ended: dict[int, dict[int, int]] = {}  # id -> {sensor id: count}
        self._episodes: dict[int, _Episode] = {}
        self._current: _Episode | None = None
        self._latest_start: int | None = None
        self._pending_layout: list[Raw] = []
        self._pending_episode: list[Raw] = []
        self.rejected: Counter[str] = Counter()
        self.handled: Counter[str] = Counter()
        self.received = 0
        self.accepted = 0
        self.segments_done = 0
        self.episodes_final = 0
        self.first_rx: float | None = None
        self.last_rx: float | None = None

    # --- inputs ---------------------------------------------------------------------------
    def set_layout(self, layout: Layout, now: float) -> bool:
        """Use ``layout`` from now on; returns False when it equals the current one."""
        old = self.layout
        if old is not None and _same_layout(old, layout):
            return False
        if old is not None:
            for ep in list(self._episodes.values()):
                if not ep.finalized:
                    self._force(ep, now)
            self._episodes = {k: v for k, v in self._episodes.items() if v.finalized}
            self._current = None
        self.layout = layout
        self._index = {int(s): i for i, s in enumerate(layout.sensor_ids)}
        self._positions = [float(p) for p in layout.positions]
        self._last_stamp = [-(2**63)] * layout.n_sensors
        for episode_id in sorted(self._infos):
            self._ensure_episode(episode_id, now)
        held, self._pending_layout = self._pending_layout, []
        for raw in held:
            self._place(*raw)
        return True

    def add_episode(
        self,
        episode_id: int,
        num_targets: int,
        start_ns: int,
        end_ns: int,
        ended_counts: dict[int, int] | None,
        now: float,
    ) -> None:
        """An EpisodeInfo: STARTED (``ended_counts`` None) or ENDED (with the counts)."""
        if episode_id not in self._infos:
            self._infos[episode_id] = (num_targets, start_ns, end_ns)
            if self._latest_start is None or start_ns > self._latest_start:
                self._latest_start = start_ns
        if ended_counts is not None:
            self._ended[episode_id] = ended_counts
        if self.layout is None:
            return
        ep = self._ensure_episode(episode_id, now)
        if ep is None or ep.finalized:
            return
        if ended_counts is not None and ep.ended is None:
            ep.ended = [0] * self.layout.n_sensors
            for sensor_id, count in ended_counts.items():
                s = self._index.get(sensor_id)
                if s is not None:
                    ep.ended[s] = count
            ep.last_activity = now
            self._advance(ep, now)
        held, self._pending_episode = self._pending_episode, []
        for raw in held:
            self._place(*raw)

    def add_detection(
        self, sensor_id: int, stamp_ns: int, position: float, velocity: float, now: float
    ) -> None:
        """One received Detection message. Cheap: no numpy, a few dict/list operations."""
        self.received += 1
        if self.first_rx is None:
            self.first_rx = now
        self.last_rx = now
        if self.layout is None:
            if self._held() >= self.config.max_buffered:
                self._reject('buffer_full', sensor_id, stamp_ns)
                return
            self.handled['before_layout'] += 1
            self._pending_layout.append((sensor_id, stamp_ns, position, velocity, now))
            return
        self._place(sensor_id, stamp_ns, position, velocity, now)

    def tick(self, now: float) -> None:
        """Timeouts: held detections without an episode, episodes that stopped short."""
        timeout = self.config.completion_timeout
        if self._pending_episode:
            keep = []
            for raw in self._pending_episode:
                if now - raw[4] > timeout:
                    self._reject('outside_episode', raw[0], raw[1])
                else:
                    keep.append(raw)
            self._pending_episode = keep
        open_eps = sorted(
            (ep for ep in self._episodes.values() if not ep.finalized), key=lambda e: e.id
        )
        for i, ep in enumerate(open_eps):
            later_active = any(o.last_activity > 0 for o in open_eps[i + 1 :])
            if (
                (ep.ended is not None or later_active)
                and ep.last_activity > 0
                and now - ep.last_activity > timeout
            ):
                self.handled['completion_timeout'] += 1
                self._force(ep, now)

    # --- state for diagnostics ------------------------------------------------------------
    def buffer_sizes(self) -> dict[str, int]:
        return {
            'buffered_open_episodes': sum(
                ep.buffered() for ep in self._episodes.values() if not ep.finalized
            ),
            'held_before_layout': len(self._pending_layout),
            'held_without_episode': len(self._pending_episode),
            'open_episodes': sum(1 for ep in self._episodes.values() if not ep.finalized),
        }

    # --- internals ------------------------------------------------------------------------
    def _held(self) -> int:
        return len(self._pending_layout) + len(self._pending_episode)

    def _reject(self, reason: str, sensor_id: int, stamp_ns: int) -> None:
        self.rejected[reason] += 1
        if self._on_reject is not None:
            self._on_reject(reason, f'sensor {sensor_id}, stamp {stamp_ns} ns')

    def _ensure_episode(self, episode_id: int, now: float) -> _Episode | None:
        ep = self._episodes.get(episode_id)
        if ep is None and episode_id in self._infos and self.layout is not None:
            num_targets, start, end = self._infos[episode_id]
            ep = _Episode(episode_id, num_targets, start, end, self.layout, self.config)
            self._episodes[episode_id] = ep
            counts = self._ended.get(episode_id)
            if counts is not None:
                ep.ended = [0] * self.layout.n_sensors
                for sensor_id, count in counts.items():
                    s = self._index.get(sensor_id)
                    if s is not None:
                        ep.ended[s] = count
        return ep

    def _find_episode(self, stamp_ns: int) -> _Episode | None:
        cur = self._current
        if cur is not None and cur.start_ns <= stamp_ns <= cur.end_ns:
            return cur
        for ep in self._episodes.values():
            if ep.start_ns <= stamp_ns <= ep.end_ns:
                self._current = ep
                return ep
        return None

    def _place(
        self, sensor_id: int, stamp_ns: int, position: float, velocity: float, now: float
    ) -> None:
        s = self._index.get(sensor_id)
        if s is None:
            self._reject('unknown_sensor', sensor_id, stamp_ns)
            return
        ep = self._find_episode(stamp_ns)
        if ep is None:
            if self._latest_start is not None and stamp_ns < self._latest_start:
                self._reject('outside_episode', sensor_id, stamp_ns)
            elif self._held() >= self.config.max_buffered:
                self._reject('buffer_full', sensor_id, stamp_ns)
            else:
                self._pending_episode.append((sensor_id, stamp_ns, position, velocity, now))
            return
        if ep.finalized:
            self._reject('after_episode_final', sensor_id, stamp_ns)
            return
        ep.received[s] += 1
        ep.last_activity = now
        reason = None
        if not (0.0 < velocity < math.inf):
            if velocity != velocity:
                reason = 'nan_velocity'
            elif velocity in (math.inf, -math.inf):
                reason = 'inf_velocity'
            else:
                reason = 'zero_velocity' if velocity == 0 else 'negative_velocity'
        elif not abs(position - self._positions[s]) <= POSITION_TOLERANCE:
            reason = 'position_mismatch'
        elif stamp_ns in ep.seen[s]:
            reason = 'duplicate'
        if reason is not None:
            self._reject(reason, sensor_id, stamp_ns)
        else:
            if stamp_ns < self._last_stamp[s]:
                self.handled['out_of_order'] += 1
            else:
                self._last_stamp[s] = stamp_ns
            stamps = ep.stamps[s]
            if len(stamps) >= ep.num_targets:
                self.handled['excess_at_sensor'] += 1
            ep.seen[s].add(stamp_ns)
            stamps.append(stamp_ns)
            ep.vels[s].append(velocity)
            self.accepted += 1
            if ep.seg_of[s] < ep.next_segment:
                self.handled['late_for_segment'] += 1
                ep.dirty = True
        if ep.seg_of[s] == ep.next_segment and ep.sensor_done(s):
            self._advance(ep, now)
        elif ep.next_segment == len(ep.segments) and ep.ended is not None:
            self._advance(ep, now)

    def _job(
        self,
        ep: _Episode,
        kind: str,
        segment: int,
        parts: tuple[Part, ...],
        now: float,
        forced: bool,
    ) -> Job:
        return Job(
            kind=kind,
            episode_id=ep.id,
            layout=ep.layout,
            n_targets=ep.num_targets,
            method=ep.method,
            associator_config=ep.associator_config,
            segment=segment,
            segments_total=len(ep.segments),
            parts=parts,
            completed_at=now,
            forced=forced,
        )

    def _advance(self, ep: _Episode, now: float, forced: bool = False) -> None:
        while ep.next_segment < len(ep.segments):
            seg = ep.segments[ep.next_segment]
            if not forced and not all(ep.sensor_done(s) for s in seg):
                return
            self._submit(self._job(ep, 'segment', ep.next_segment, (ep.part(seg),), now, forced))
            ep.next_segment += 1
            self.segments_done += 1
        if not forced:
            if ep.ended is None or not all(ep.sensor_done(s) for s in range(len(ep.seg_of))):
                return
        if ep.dirty:
            parts = tuple(ep.part(seg) for seg in ep.segments)
            self._submit(self._job(ep, 'rerun', len(ep.segments), parts, now, forced))
        else:
            self._submit(self._job(ep, 'final', len(ep.segments), (), now, forced))
        ep.finalized = True
        self.episodes_final += 1
        # Free the buffers; keep the window so that late detections are recognised.
        ep.stamps = ep.vels = []
        ep.seen = []

    def _force(self, ep: _Episode, now: float) -> None:
        self._advance(ep, now, forced=True)


def _same_layout(a: Layout, b: Layout) -> bool:
    return (
        a.road_length == b.road_length
        and a.names == b.names
        and np.array_equal(a.sensor_ids, b.sensor_ids)
        and np.array_equal(a.positions, b.positions)
    )
