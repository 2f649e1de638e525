"""Live assembly of detections into episodes and road segments (ROS-free).

The association node feeds every received detection and episode message in here; this module
decides, cheaply per message, which episode and segment a detection belongs to, whether it is
valid, and when a segment is complete. Complete segments come out as :class:`Job` objects,
strictly in segment order per episode, for the solver (:mod:`mlkm_assoc.solver`).

Policies (README "Association node"):

* Validation: a detection's velocity, stamp and measured length (NaN = not measured) must
  lie inside the physical :class:`~mlkm_core.bounds.Bounds` (node parameters), its sensor
  id must be in the layout and its position match that sensor's, its lane be -1 (unknown)
  or, where the layout gives the sensor's lane count, below it. A duplicate is a second
  detection with the same (sensor, lane, stamp), or, lane unknown, the same (sensor, stamp,
  velocity): two vehicles passing one station in different lanes within the same
  nanosecond are both kept. Refused detections never count towards completion.
* Episode assignment: a detection belongs to the episode whose [start, end] window (from
  EpisodeInfo) holds its stamp. Detections whose episode is not known yet are held (topics
  are not ordered against each other) and placed when the EpisodeInfo arrives; held longer
  than ``completion_timeout`` or older than a later known episode: rejected
  ``outside_episode``.
* Completion: a sensor is done for an episode when it has ``num_targets`` accepted detections
  (the paper's setting, before the episode has ended) or, once ENDED has arrived, as many
  accepted detections as ENDED counts. A segment is complete when all its sensors are done;
  segments go to the solver in order (segment e+1 waits for e). The final association is
  published when every segment went out and ENDED's counts are met, or ``completion_timeout``
  seconds after the last input once the episode ended (counted ``completion_timeout``), or
  ``episode_timeout`` seconds after the last input of an episode that never ended (its
  simulator died; counted ``episode_timeout``). Detections ENDED announced that never arrived
  are counted as ``missing``. An episode of which this node saw no detection at all (it was
  down) gets no final; it is counted in ``episodes_unseen`` and its detections as missing.
* A detection that arrives for a segment already solved (clutter: a sensor with more
  detections than targets; or a stamp out of order) is kept; the episode's final association
  is then recomputed from scratch over every detection, so the final tracks hold it.
* Runs: a restarted simulator numbers its episodes from 0 again. A new run is recognised by
  a layout published later than the current run began (same content or not), an EpisodeInfo
  for a known id with another window or number of targets, a STARTED for a known id
  published at another time, or an EpisodeInfo for an already forgotten id published later
  than any of this run. The open episodes of the old run are then finalised with what they
  have, and its bookkeeping is forgotten.
* Memory: buffers of an episode are freed when it is finalised; at most
  ``max_finished_episodes`` finished episodes are remembered (to reject their late
  detections as ``after_episode_final``); older ones are forgotten.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable

import numpy as np

from mlkm_assoc.episodes import AssociationConfig, Episode, Job, Part
from mlkm_core.bounds import REASONS as BOUNDS_REASONS
from mlkm_core.bounds import Bounds
from mlkm_core.types import UNKNOWN_LANE, Layout

__all__ = ['REJECT_REASONS', 'Assembler', 'AssociationConfig', 'Job', 'Part']

#: Reasons a detection is rejected (not associated).
REJECT_REASONS = (
    *BOUNDS_REASONS,
    'unknown_sensor',
    'position_mismatch',
    'lane_out_of_range',
    'duplicate',
    'outside_episode',
    'after_episode_final',
    'buffer_full',
)
#: Tolerance between a detection's position and its sensor's layout position [m].
POSITION_TOLERANCE = 1e-3
NS_PER_S = 1_000_000_000

#: sensor id, stamp [ns], position, velocity, t_rx, lane, length
Raw = tuple[int, int, float, float, float, int, float]
Info = tuple[int, int, int]  # num_targets, start [ns], end [ns]


class Assembler:
    """Episode and segment bookkeeping; emits :class:`Job` s through ``submit``."""

    def __init__(
        self,
        config: AssociationConfig,
        submit: Callable[[Job], None],
        on_reject: Callable[[str, str], None] | None = None,
    ) -> None:
        self._config = config
        self.bounds: Bounds = config.bounds()
        self._submit = submit
        self._on_reject = on_reject
        self.layout: Layout | None = None
        self._layout_stamp = -1
        self._index: dict[int, int] = {}
        self._positions: list[float] = []
        self._lane_counts: tuple[int, ...] | None = None
        self._pending_layout: list[Raw] = []
        self._pending_episode: list[Raw] = []
        self.rejected: Counter[str] = Counter()
        self.handled: Counter[str] = Counter()
        self.received = 0
        self.accepted = 0
        self.segments_done = 0
        self.episodes_final = 0
        self.episodes_unseen = 0  # episodes this node saw no detection of (no final)
        self.missing = 0  # detections ENDED announced that never arrived
        self.runs = 1
        self.first_rx: float | None = None
        self.last_rx: float | None = None
        self._run_stamp = -1  # publication stamp of the message that began this run [ns]
        self._forget_run()

    def _forget_run(self) -> None:
        self._infos: dict[int, Info] = {}
        self._started: dict[int, int] = {}  # id -> publication stamp of its STARTED [ns]
        self._ended: dict[int, dict[int, int]] = {}  # id -> {sensor id: count}
        self._episodes: dict[int, Episode] = {}
        self._finished: list[int] = []  # finalised episode ids, oldest first
        self._forgotten = -1  # episode ids up to this one were forgotten
        self._info_stamp = -1  # latest publication stamp of an EpisodeInfo of this run
        self._current: Episode | None = None
        self._latest_start: int | None = None
        self._last_stamp = [-(2**63)] * (0 if self.layout is None else self.layout.n_sensors)

    @property
    def config(self) -> AssociationConfig:
        return self._config

    @config.setter
    def config(self, config: AssociationConfig) -> None:
        """New settings (from the next episode on; the bounds at once)."""
        self.bounds = config.bounds()
        self._config = config

    # --- inputs ---------------------------------------------------------------------------
    def set_layout(
        self,
        layout: Layout,
        now: float,
        published_ns: int = 0,
        lane_counts: tuple[int, ...] | None = None,
    ) -> bool:
        """Use ``layout`` from now on; returns False when it is the current one.

        ``published_ns``: the message's publication stamp; a layout published after the
        current run began starts a new run even when its content is the same (the simulator
        restarted). ``lane_counts``: lanes per sensor (None: unknown).
        """
        old = self.layout
        lane_counts = None if lane_counts is None else tuple(int(n) for n in lane_counts)
        if lane_counts is not None and len(lane_counts) != layout.n_sensors:
            raise ValueError(f'{len(lane_counts)} lane counts for {layout.n_sensors} sensors')
        if old is not None and _same_layout(old, layout) and lane_counts == self._lane_counts:
            if published_ns == self._layout_stamp or published_ns <= self._run_stamp:
                return False
        self._layout_stamp = published_ns
        if old is not None:
            self._new_run(now, published_ns)
        self.layout = layout
        self._index = {int(s): i for i, s in enumerate(layout.sensor_ids)}
        self._positions = [float(p) for p in layout.positions]
        self._lane_counts = lane_counts
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
        published_ns: int = 0,
    ) -> None:
        """An EpisodeInfo: STARTED (``ended_counts`` None) or ENDED (with the counts), already
        validated; ``published_ns`` is its header stamp (when it was published)."""
        info = (num_targets, start_ns, end_ns)
        started = ended_counts is None
        if self._is_new_run(episode_id, info, started, published_ns):
            self._new_run(now, published_ns)
        elif episode_id <= self._forgotten:
            self.handled['stale_episode_info'] += 1
            return
        self._info_stamp = max(self._info_stamp, published_ns)
        if episode_id not in self._infos:
            self._infos[episode_id] = info
            if self._latest_start is None or start_ns > self._latest_start:
                self._latest_start = start_ns
        if started:
            self._started.setdefault(episode_id, published_ns)
        else:
            self._ended[episode_id] = ended_counts
        if self.layout is None:
            return
        ep = self._ensure_episode(episode_id, now)
        if ep is None or ep.finalized:
            return
        if ended_counts is not None and ep.ended is None:
            ep.set_ended(ended_counts, self._index)
            ep.last_activity = now
            self._advance(ep, now)
        held, self._pending_episode = self._pending_episode, []
        for raw in held:
            self._place(*raw)

    def add_detection(
        self,
        sensor_id: int,
        stamp_ns: int,
        position: float,
        velocity: float,
        now: float,
        lane: int = UNKNOWN_LANE,
        length: float = math.nan,
    ) -> None:
        """One received Detection message (``lane`` -1 and ``length`` NaN: unknown). Cheap:
        no numpy, a few dict/list operations."""
        self.received += 1
        if self.first_rx is None:
            self.first_rx = now
        self.last_rx = now
        if self.layout is None:
            reason = self.bounds.refuse(stamp_ns / NS_PER_S, velocity, length)
            if reason is None and lane < UNKNOWN_LANE:
                reason = 'lane_out_of_range'
            if reason is not None:
                self._reject(reason, sensor_id, stamp_ns, velocity, lane, length)
            elif self._held() >= self._config.max_buffered:
                self._reject('buffer_full', sensor_id, stamp_ns, velocity, lane, length)
            else:
                self.handled['before_layout'] += 1
                self._pending_layout.append(
                    (sensor_id, stamp_ns, position, velocity, now, lane, length)
                )
            return
        self._place(sensor_id, stamp_ns, position, velocity, now, lane, length)

    def tick(self, now: float) -> None:
        """Timeouts: held detections without an episode, episodes that stopped short."""
        timeout = self._config.completion_timeout
        if self._pending_episode:
            keep = []
            for raw in self._pending_episode:
                if now - raw[4] > timeout:
                    self._reject('outside_episode', raw[0], raw[1], raw[3], raw[5], raw[6])
                else:
                    keep.append(raw)
            self._pending_episode = keep
        open_eps = sorted(
            (ep for ep in self._episodes.values() if not ep.finalized), key=lambda e: e.id
        )
        for i, ep in enumerate(open_eps):
            idle = now - ep.last_activity
            later_active = any(o.accepted > 0 for o in open_eps[i + 1 :])
            if (ep.ended is not None or later_active) and idle > timeout:
                self.handled['completion_timeout'] += 1
                self._force(ep, now)
            elif idle > self._config.episode_timeout:
                self.handled['episode_timeout'] += 1
                self._force(ep, now)

    # --- state ----------------------------------------------------------------------------
    def knows_episode(self, episode_id: int, start_ns: int | None = None) -> bool:
        """Whether this run has the EpisodeInfo of ``episode_id`` (with that start)."""
        info = self._infos.get(episode_id)
        return info is not None and (start_ns is None or info[1] == start_ns)

    def episode_ended(self, episode_id: int) -> bool:
        """Whether the ENDED message of ``episode_id`` arrived in this run."""
        return episode_id in self._ended

    def remembered_episodes(self) -> int:
        return len(self._episodes)

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

    def _reject(
        self,
        reason: str,
        sensor_id: int,
        stamp_ns: int,
        velocity: float,
        lane: int = UNKNOWN_LANE,
        length: float = math.nan,
    ) -> None:
        self.rejected[reason] += 1
        if self._on_reject is not None:
            if reason in BOUNDS_REASONS:
                detail = self.bounds.describe(reason)
            elif reason == 'lane_out_of_range':
                s = self._index.get(sensor_id)
                known = self._lane_counts is not None and s is not None
                detail = (
                    f'lane must be -1 (unknown) or in [0, {self._lane_counts[s] - 1}]'
                    if known
                    else 'lane must be -1 (unknown) or >= 0'
                )
            else:
                detail = reason
            self._on_reject(
                reason,
                f'sensor {sensor_id}, lane {lane}, stamp {stamp_ns} ns, velocity {velocity!r} '
                f'm/s, length {length!r} m: {detail}',
            )

    def _is_new_run(self, episode_id: int, info: Info, started: bool, published_ns: int) -> bool:
        known = self._infos.get(episode_id)
        if known is not None:
            if known != info:
                return published_ns >= self._run_stamp
            first = self._started.get(episode_id)
            return (
                started
                and first is not None
                and published_ns != first
                and published_ns > self._run_stamp
            )
        return episode_id <= self._forgotten and published_ns > self._info_stamp

    def _new_run(self, now: float, run_stamp: int) -> None:
        """The source restarted: close the old run's episodes, forget its bookkeeping.
        EpisodeInfos published after ``run_stamp`` already belong to the new run: kept."""
        keep = {
            k: v
            for k, v in self._infos.items()
            if self._started.get(k, -1) >= run_stamp and run_stamp > self._run_stamp
        }
        for ep in sorted(self._episodes.values(), key=lambda e: e.id):
            if not ep.finalized and (ep.id not in keep or ep.accepted > 0):
                keep.pop(ep.id, None)
                self._force(ep, now)
        started = {k: self._started[k] for k in keep if k in self._started}
        ended = {k: self._ended[k] for k in keep if k in self._ended}
        self._forget_run()
        self._infos, self._started, self._ended = keep, started, ended
        if keep:
            self._latest_start = max(start for _, start, _ in keep.values())
        self._run_stamp = max(self._run_stamp, run_stamp)
        self.runs += 1

    def _ensure_episode(self, episode_id: int, now: float) -> Episode | None:
        ep = self._episodes.get(episode_id)
        if ep is None and episode_id in self._infos and self.layout is not None:
            num_targets, start, end = self._infos[episode_id]
            ep = Episode(episode_id, num_targets, start, end, self.layout, self._config, now)
            self._episodes[episode_id] = ep
            counts = self._ended.get(episode_id)
            if counts is not None:
                ep.set_ended(counts, self._index)
        return ep

    def _find_episode(self, stamp_ns: int) -> Episode | None:
        cur = self._current
        if cur is not None and cur.start_ns <= stamp_ns <= cur.end_ns:
            return cur
        for ep in self._episodes.values():
            if ep.start_ns <= stamp_ns <= ep.end_ns:
                self._current = ep
                return ep
        return None

    def _place(
        self,
        sensor_id: int,
        stamp_ns: int,
        position: float,
        velocity: float,
        now: float,
        lane: int = UNKNOWN_LANE,
        length: float = math.nan,
    ) -> None:
        raw = (sensor_id, stamp_ns, position, velocity, now, lane, length)
        s = self._index.get(sensor_id)
        if s is None:
            self._reject('unknown_sensor', sensor_id, stamp_ns, velocity, lane, length)
            return
        reason = self.bounds.refuse(stamp_ns / NS_PER_S, velocity, length)
        if reason is None and not abs(position - self._positions[s]) <= POSITION_TOLERANCE:
            reason = 'position_mismatch'
        if reason is None and not self._lane_ok(s, lane):
            reason = 'lane_out_of_range'
        ep = self._find_episode(stamp_ns)
        if reason is not None:
            if ep is not None and not ep.finalized:
                ep.rejected[s] += 1  # announced by ENDED, so not missing
                ep.last_activity = now
            self._reject(reason, sensor_id, stamp_ns, velocity, lane, length)
            return
        if ep is None:
            if self._latest_start is not None and stamp_ns < self._latest_start:
                self._reject('outside_episode', sensor_id, stamp_ns, velocity, lane, length)
            elif self._held() >= self._config.max_buffered:
                self._reject('buffer_full', sensor_id, stamp_ns, velocity, lane, length)
            else:
                self._pending_episode.append(raw)
            return
        if ep.finalized:
            self._reject('after_episode_final', sensor_id, stamp_ns, velocity, lane, length)
            return
        ep.last_activity = now
        key = (stamp_ns, lane) if lane != UNKNOWN_LANE else (stamp_ns, lane, velocity)
        if key in ep.seen[s]:
            ep.rejected[s] += 1
            self._reject('duplicate', sensor_id, stamp_ns, velocity, lane, length)
            return
        if stamp_ns < self._last_stamp[s]:
            self.handled['out_of_order'] += 1
        else:
            self._last_stamp[s] = stamp_ns
        stamps = ep.stamps[s]
        if len(stamps) >= ep.num_targets:
            self.handled['excess_at_sensor'] += 1
        ep.seen[s].add(key)
        stamps.append(stamp_ns)
        ep.vels[s].append(velocity)
        ep.lanes[s].append(lane)
        ep.lengths[s].append(length)
        ep.accepted += 1
        self.accepted += 1
        if ep.seg_of[s] < ep.next_segment:
            self.handled['late_for_segment'] += 1
            ep.dirty = True
        if ep.seg_of[s] == ep.next_segment and ep.sensor_done(s):
            self._advance(ep, now)
        elif ep.next_segment == len(ep.segments) and ep.ended is not None:
            self._advance(ep, now)

    def _lane_ok(self, s: int, lane: int) -> bool:
        if lane == UNKNOWN_LANE:
            return True
        if lane < 0:
            return False
        return self._lane_counts is None or lane < self._lane_counts[s]

    def _job(
        self, ep: Episode, kind: str, parts: tuple[Part, ...], now: float, forced: bool
    ) -> Job:
        return Job(
            kind=kind,
            episode_id=ep.id,
            layout=ep.layout,
            n_targets=ep.num_targets,
            method=ep.method,
            associator_config=ep.associator_config,
            segments_total=len(ep.segments),
            parts=parts,
            completed_at=now,
            forced=forced,
            missing=ep.missing() if kind != 'segment' else 0,
        )

    def _advance(self, ep: Episode, now: float, forced: bool = False) -> None:
        while ep.next_segment < len(ep.segments):
            seg = ep.segments[ep.next_segment]
            if not forced and not all(ep.sensor_done(s) for s in seg):
                return
            self._submit(self._job(ep, 'segment', (ep.part(seg),), now, forced))
            ep.next_segment += 1
            self.segments_done += 1
        if not forced:
            if ep.ended is None or not all(ep.sensor_done(s) for s in range(len(ep.seg_of))):
                return
        if ep.dirty:
            parts = tuple(ep.part(seg) for seg in ep.segments)
            self._submit(self._job(ep, 'rerun', parts, now, forced))
        else:
            self._submit(self._job(ep, 'final', (), now, forced))
        self.missing += ep.missing()
        self.episodes_final += 1
        self._finish(ep)

    def _force(self, ep: Episode, now: float) -> None:
        """Finalise ``ep`` with what it has; without a single detection: no final at all."""
        if ep.accepted == 0:
            self.episodes_unseen += 1
            self.missing += ep.missing()
            self._finish(ep)
            return
        self._advance(ep, now, forced=True)

    def _finish(self, ep: Episode) -> None:
        ep.finalized = True
        ep.free()
        self._finished.append(ep.id)
        while len(self._finished) > self._config.max_finished_episodes:
            old = self._finished.pop(0)
            if self._episodes.get(old) is self._current:
                self._current = None
            self._episodes.pop(old, None)
            self._infos.pop(old, None)
            self._started.pop(old, None)
            self._ended.pop(old, None)
            self._forgotten = max(self._forgotten, old)


def _same_layout(a: Layout, b: Layout) -> bool:
    return (
        a.road_length == b.road_length
        and a.names == b.names
        and np.array_equal(a.sensor_ids, b.sensor_ids)
        and np.array_equal(a.positions, b.positions)
    )
