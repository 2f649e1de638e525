"""Live assembly of detections into episodes and road segments (ROS-free).

The association node feeds every received detection and episode message in here; this module
decides, cheaply per message, which episode and segment a detection belongs to, whether it is
valid, and when a segment is complete. Complete segments come out as :class:`Job` objects,
strictly in segment order per episode, for the solver (:mod:`mlkm_assoc.solver`).

Policies (README "Association node"):

* Validation (:mod:`mlkm_assoc.validation`): the bounds, the sensor, its position and lane,
  and duplicates. Refused detections never count towards completion.
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
* Runs: a restarted simulator numbers its episodes from 0 again; :mod:`mlkm_assoc.runs`
  recognises a new run. The open episodes of the old run are then finalised with what they
  have, and its bookkeeping is forgotten.
* Memory: buffers of an episode are freed when it is finalised; at most
  ``max_finished_episodes`` finished episodes are remembered (to reject their late
  detections as ``after_episode_final``); older ones are forgotten.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable

from mlkm_assoc.completion import Completion
from mlkm_assoc.episodes import AssociationConfig, Episode, Job, Part
from mlkm_assoc.runs import RunBook
from mlkm_assoc.validation import (
    NS_PER_S,
    POSITION_TOLERANCE,
    REJECT_REASONS,
    DetectionCheck,
    HoldsEarly,
    Received,
    same_layout,
)
from mlkm_core.bounds import Bounds
from mlkm_core.types import UNKNOWN_LANE, Layout, duplicate_key

__all__ = [
    'NS_PER_S',
    'POSITION_TOLERANCE',
    'REJECT_REASONS',
    'Assembler',
    'AssociationConfig',
    'Job',
    'Part',
]


def _count(name: str, doc: str) -> property:
    """A read-only count of the assembler's :class:`Completion`."""
    return property(lambda self: getattr(self._completion, name), doc=doc)


class Assembler(HoldsEarly):
    """Episode and segment bookkeeping; emits :class:`Job` s through ``submit``."""

    def __init__(
        self,
        config: AssociationConfig,
        submit: Callable[[Job], None],
        on_reject: Callable[[str, str], None] | None = None,
    ) -> None:
        self._config = config
        self._check = DetectionCheck(config.bounds())
        self._on_reject = on_reject
        self.layout: Layout | None = None
        self._layout_stamp = -1
        self._pending_layout: list[Received] = []
        self._pending_episode: list[Received] = []
        self.rejected: Counter[str] = Counter()
        self.handled: Counter[str] = Counter()
        self.received = 0
        self.accepted = 0
        self._completion = Completion(submit)
        self.runs = 1
        self.first_rx: float | None = None
        self.last_rx: float | None = None
        self._run = RunBook()
        self._forget_run()

    def _forget_run(self) -> None:
        """Forget the episodes of the run (the RunBook forgets its EpisodeInfos itself)."""
        self._episodes: dict[int, Episode] = {}
        self._finished: list[int] = []  # finalised episode ids, oldest first
        self._current: Episode | None = None
        self._last_stamp = [-(2**63)] * (0 if self.layout is None else self.layout.n_sensors)

    @property
    def config(self) -> AssociationConfig:
        return self._config

    @config.setter
    def config(self, config: AssociationConfig) -> None:
        """New settings (from the next episode on; the bounds at once)."""
        self._check.bounds = config.bounds()
        self._config = config

    @property
    def bounds(self) -> Bounds:
        return self._check.bounds

    # the counts of the episodes' completion (mlkm_assoc.completion)
    segments_done = _count('segments_done', 'segments handed to the solver')
    episodes_final = _count('episodes_final', 'episodes whose final went to the solver')
    episodes_unseen = _count('episodes_unseen', 'episodes this node saw no detection of')
    missing = _count('missing', 'detections ENDED announced that never arrived')

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
        if old is not None and same_layout(old, layout) and lane_counts == self._check.lane_counts:
            if published_ns == self._layout_stamp or published_ns <= self._run.run_stamp:
                return False
        self._layout_stamp = published_ns
        if old is not None:
            self._new_run(now, published_ns)
        self.layout = layout
        self._check.set_layout(layout, lane_counts)
        self._last_stamp = [-(2**63)] * layout.n_sensors
        for episode_id in sorted(self._run.infos):
            self._ensure_episode(episode_id, now)
        held, self._pending_layout = self._pending_layout, []
        self._place_held(held)
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
        if self._run.is_new_run(episode_id, info, started, published_ns):
            self._new_run(now, published_ns)
        elif episode_id <= self._run.forgotten:
            self.handled['stale_episode_info'] += 1
            return
        self._run.record(episode_id, info, ended_counts, published_ns)
        if self.layout is None:
            return
        ep = self._ensure_episode(episode_id, now)
        if ep is None or ep.finalized:
            return
        if ended_counts is not None and ep.ended is None:
            ep.set_ended(ended_counts, self._check.index)
            ep.last_activity = now
            self._advance(ep, now)
        held, self._pending_episode = self._pending_episode, []
        self._place_held(held)

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
        raw = Received(sensor_id, stamp_ns, position, velocity, lane, length, now)
        if self.layout is None:
            reason = self._check.refuse_unplaced(stamp_ns, velocity, lane, length)
            room = self._held() < self._config.max_buffered
            self._hold_early(raw, reason, room, self._pending_layout)
            return
        self._place(raw)

    def tick(self, now: float) -> None:
        """Timeouts: held detections without an episode, episodes that stopped short."""
        timeout = self._config.completion_timeout
        if self._pending_episode:
            keep = []
            for raw in self._pending_episode:
                if now - raw.received > timeout:
                    self._reject('outside_episode', raw)
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
        info = self._run.infos.get(episode_id)
        return info is not None and (start_ns is None or info[1] == start_ns)

    def episode_ended(self, episode_id: int) -> bool:
        """Whether the ENDED message of ``episode_id`` arrived in this run."""
        return episode_id in self._run.ended

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

    def _reject(self, reason: str, raw: Received) -> None:
        self.rejected[reason] += 1
        if self._on_reject is not None:
            self._on_reject(reason, self._check.describe(reason, raw))

    def _new_run(self, now: float, run_stamp: int) -> None:
        """The source restarted: close the old run's episodes, forget its bookkeeping.
        EpisodeInfos published after ``run_stamp`` already belong to the new run: kept."""
        keep = self._run.kept_for_new_run(run_stamp)
        for ep in sorted(self._episodes.values(), key=lambda e: e.id):
            if not ep.finalized and (ep.id not in keep or ep.accepted > 0):
                keep.pop(ep.id, None)
                self._force(ep, now)
        self._run.restart(keep, run_stamp)
        self._forget_run()
        self.runs += 1

    def _ensure_episode(self, episode_id: int, now: float) -> Episode | None:
        ep = self._episodes.get(episode_id)
        if ep is None and episode_id in self._run.infos and self.layout is not None:
            num_targets, start, end = self._run.infos[episode_id]
            ep = Episode(episode_id, num_targets, start, end, self.layout, self._config, now)
            self._episodes[episode_id] = ep
            counts = self._run.ended.get(episode_id)
            if counts is not None:
                ep.set_ended(counts, self._check.index)
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

    def _place(self, raw: Received) -> None:
        sensor_id, stamp_ns, position, velocity, lane, length, now = raw
        s, reason = self._check.check(raw)
        if s < 0:
            self._reject(reason, raw)
            return
        ep = self._find_episode(stamp_ns)
        if reason is not None:
            if ep is not None and not ep.finalized:
                ep.rejected[s] += 1  # announced by ENDED, so not missing
                ep.last_activity = now
            self._reject(reason, raw)
            return
        if ep is None:
            latest_start = self._run.latest_start
            if latest_start is not None and stamp_ns < latest_start:
                self._reject('outside_episode', raw)
            elif self._held() >= self._config.max_buffered:
                self._reject('buffer_full', raw)
            else:
                self._pending_episode.append(raw)
            return
        if ep.finalized:
            self._reject('after_episode_final', raw)
            return
        ep.last_activity = now
        key = duplicate_key(sensor_id, lane, stamp_ns, velocity)
        if key in ep.seen[s]:
            ep.rejected[s] += 1
            self._reject('duplicate', raw)
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

    def _advance(self, ep: Episode, now: float) -> None:
        if self._completion.advance(ep, now):
            self._finish(ep)

    def _force(self, ep: Episode, now: float) -> None:
        """Finalise ``ep`` with what it has (:meth:`Completion.force`)."""
        if self._completion.force(ep, now):
            self._finish(ep)

    def _finish(self, ep: Episode) -> None:
        ep.finalized = True
        ep.free()
        self._finished.append(ep.id)
        while len(self._finished) > self._config.max_finished_episodes:
            old = self._finished.pop(0)
            if self._episodes.get(old) is self._current:
                self._current = None
            self._episodes.pop(old, None)
            self._run.drop(old)
