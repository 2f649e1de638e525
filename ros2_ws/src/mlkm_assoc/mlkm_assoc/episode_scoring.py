"""The scorer's episodes mode: each episode's final tracks against its ground truth.

The FINAL TrackArray of an episode is joined with its GroundTruth messages on (sensor id,
lane, stamp in integer ns; lane -1 where unknown) and scored with the core's one scoring
function, ``mlkm_core.metrics.score``; the policies (complete truth, runs, memory) are those
of :mod:`mlkm_assoc.scorer_node`, which feeds every message the stream mode
(:mod:`mlkm_assoc.stream_scoring`) did not take in here.

An episode with final tracks waits for its whole ground truth (the ENDED counts) while truth
keeps arriving: it is scored with the truth at hand only once neither any ground truth nor
any input for the episode arrived for ``truth_timeout`` seconds (the source stopped, or its
truth was lost). An episode without any true detection at hand has no accuracy: it is not
published, only logged and counted (``episodes_unscored``).
"""

from __future__ import annotations

import math
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Iterable

import numpy as np

from mlkm_assoc.episode_inputs import (
    Key,
    OpenEpisode,
    ScoredEpisode,
    ScorerConfig,
    Window,
    check_tracks,
    valid_stamp_ns,
)
from mlkm_core.metrics import score
from mlkm_core.types import Detections
from mlkm_ros import conversions as conv
from road_sensor_msgs.msg import EpisodeInfo, GroundTruth, TrackArray


class EpisodeScoring:
    """Open and scored episodes of the current run, the running mean and the counts.

    ``node`` gives the logger and the clock, ``score_pub`` takes the AssociationScore
    messages, ``sensor_index`` maps a sensor id to its index in road order and ``reject``
    counts and logs a refused input (reason, detail)."""

    def __init__(
        self,
        node,
        score_pub,
        config: ScorerConfig,
        sensor_index: Callable[[int], int],
        reject: Callable[[str, str], None],
    ) -> None:
        self._node = node
        self._score_pub = score_pub
        self.config = config
        self._sensor_index = sensor_index
        self._reject = reject
        self._open: dict[int, OpenEpisode] = {}  # unscored episodes, by id
        self._scored: OrderedDict[int, ScoredEpisode] = OrderedDict()  # oldest first
        self._buffered = 0  # truth messages held in self._open
        self.sum = 0.0  # accuracies in the mean
        self.in_mean = 0
        self.incomplete = 0  # published with truth_complete false
        self.last_truth_rx = -math.inf  # monotonic time the last kept ground truth arrived [s]
        self.events: Counter[str] = Counter({'episodes_unscored': 0})

    def waiting(self) -> list[tuple[int, str]]:
        """The episodes whose final tracks came and which wait for truth: (id, what is
        missing), oldest first."""
        out = []
        for episode, ep in sorted(self._open.items(), key=lambda item: item[1].last_rx):
            if ep.final is None:
                continue
            inside = [k for k in ep.truth if ep.inside(k[1])]
            if ep.counts is None:
                out.append((episode, f'{len(inside)} received, ENDED not yet'))
                continue
            have = Counter(k[0] for k in inside)
            missing = sum(max(0, n - have[s]) for s, n in ep.counts.items())
            out.append((episode, f'{missing} of {sum(ep.counts.values())} missing'))
        return out

    def diagnostics(self, now: float) -> dict[str, object]:
        waiting = self.waiting()
        idle = now - self.last_truth_rx
        return {
            'episodes_scored': self.in_mean,
            'episodes_incomplete': self.incomplete,
            'mean_accuracy': f'{self.sum / self.in_mean:.6f}' if self.in_mean else '',
            'open_episodes': len(self._open),
            'buffered_truth': self._buffered,
            'remembered_scored': len(self._scored),
            'episodes_waiting_for_truth': len(waiting),
            'truth_waiting': '; '.join(f'episode {e}: {what}' for e, what in waiting[:10]),
            'truth_idle': f'{idle:.3f}' if math.isfinite(idle) else '',
        }

    # --- inputs ---------------------------------------------------------------------------
    def on_episode(self, msg: EpisodeInfo) -> None:
        """An EpisodeInfo (the stream mode saw it already)."""
        try:
            info = conv.episode_from_msg(msg)
        except ValueError as exc:
            self._reject('invalid_episode', f'episode {msg.episode_id}: {exc}')
            return
        episode, now = info.episode_id, time.monotonic()
        window = (info.num_targets, info.start_ns, info.end_ns)
        started = info.counts is None
        pending = self._open.get(episode)
        known = pending if pending is not None else self._scored.get(episode)
        if known is not None and known.window is not None:
            first = known.started_ns
            restarted = started and first is not None and info.published_ns != first
            if known.window != window or restarted:
                self._node.get_logger().info(
                    f'episode {episode}: EpisodeInfo of a new run of the source; '
                    'forgetting the previous one'
                )
                self._restart_episode(episode, window, now)
            elif pending is None:
                return  # a repeated EpisodeInfo of a scored episode
        ep = self._episode(episode, now)
        ep.window = window
        if started:
            ep.started_ns = ep.started_ns if ep.started_ns is not None else info.published_ns
        else:
            ep.counts = info.counts
        self._try(episode)

    def on_truth(self, msg: GroundTruth) -> None:
        """A GroundTruth message the stream mode did not take."""
        try:
            stamp = valid_stamp_ns(msg.header.stamp)
        except ValueError as exc:
            self._reject('invalid_truth', f'episode {msg.episode_id}: {exc}')
            return
        episode, now = msg.episode_id, time.monotonic()
        done = self._scored.get(episode)
        if done is not None and episode not in self._open:
            if done.window is None or done.window[1] <= stamp <= done.window[2]:
                self.events['truth_after_score'] += 1
                return
        key = (int(msg.sensor_id), stamp, int(msg.lane))
        ep = self._open.get(episode)
        if (
            ep is None or key not in ep.truth
        ) and self._buffered >= self.config.max_buffered_truth:
            self._reject(
                'truth_buffer_full',
                f'episode {episode}: {self._buffered} ground-truth messages held already',
            )
            return
        ep = self._episode(episode, now)
        if key not in ep.truth:
            self._buffered += 1
        ep.truth[key] = (conv.ground_truth_target(msg), float(msg.true_velocity))
        self.last_truth_rx = now
        self._try(episode)

    def on_tracks(self, msg: TrackArray) -> None:
        """A TrackArray the stream mode did not take."""
        try:
            stamps = check_tracks(msg)
        except ValueError as exc:
            self._reject('invalid_tracks', f'episode {msg.episode_id}: {exc}')
            return
        if not msg.final:
            return
        episode, now = msg.episode_id, time.monotonic()
        done = self._scored.get(episode)
        if done is not None and episode not in self._open:
            w = done.window
            if w is None or all(w[1] <= s <= w[2] for s in stamps):
                self.events['final_after_score'] += 1
                return
        ep = self._episode(episode, now)
        ep.final = msg
        self._try(episode)

    def tick(self, now: float) -> None:
        """Score the episodes whose truth stopped coming, drop those without final tracks.

        An episode with final tracks waits while ground truth keeps arriving (the truth of
        one source comes in order, so an earlier episode's truth still arriving means its
        own is yet to come); it gives up once no truth at all and no input for the episode
        arrived for ``truth_timeout`` seconds."""
        cfg = self.config
        for episode, ep in list(self._open.items()):
            idle = now - max(ep.last_rx, self.last_truth_rx)
            if ep.final is not None and idle > cfg.truth_timeout:
                self._node.get_logger().warning(
                    f'episode {episode}: no ground truth for {cfg.truth_timeout:g} s; scoring '
                    f'with the {len(ep.truth)} messages at hand '
                    f'({"unknown" if ep.counts is None else sum(ep.counts.values())} expected)'
                )
                self._score(episode)
            elif ep.final is None and now - ep.last_rx > cfg.forget_after:
                self._drop(episode, f'no final tracks for {cfg.forget_after:g} s')

    # --- bookkeeping ----------------------------------------------------------------------
    def _episode(self, episode: int, now: float) -> OpenEpisode:
        """The open record of ``episode`` (created, and the oldest dropped past the limit)."""
        ep = self._open.get(episode)
        if ep is None:
            while len(self._open) >= self.config.max_open_episodes:
                oldest = min(self._open, key=lambda k: self._open[k].last_rx)
                if self._open[oldest].final is not None:
                    self._score(oldest)
                else:
                    self._drop(oldest, f'more than {self.config.max_open_episodes} open')
            ep = self._open[episode] = OpenEpisode(last_rx=now)
        ep.last_rx = now
        return ep

    def announced_open(self) -> bool:
        """Whether an episode an EpisodeInfo announced is still unscored."""
        return any(ep.window is not None for ep in self._open.values())

    def forget_unannounced(self) -> None:
        """The source is a stream: drop the truth held for episodes no EpisodeInfo announced
        (stream mode kept its own copy)."""
        for episode, ep in list(self._open.items()):
            if ep.window is None and ep.final is None:
                self._buffered -= len(self._open.pop(episode).truth)

    def _drop(self, episode: int, why: str) -> None:
        ep = self._open.pop(episode)
        self._buffered -= len(ep.truth)
        self.events['episodes_dropped'] += 1
        self._node.get_logger().warning(
            f'episode {episode}: dropped unscored ({why}; {len(ep.truth)} ground-truth messages)'
        )

    def _restart_episode(self, episode: int, window: Window, now: float) -> None:
        """A new run of ``episode``: the old one is scored with what it has (if its final
        came) or forgotten; truth that only the new window holds is kept for the new run."""
        self._scored.pop(episode, None)
        old = self._open.get(episode)
        if old is None:
            return
        moved = {
            k: v
            for k, v in old.truth.items()
            if not old.inside(k[1]) and window[1] <= k[1] <= window[2]
        }
        for k in moved:
            del old.truth[k]
        if old.final is not None:
            self._score(episode)
        else:
            self._drop(episode, 'a new run of the source began')
        self._scored.pop(episode, None)
        if moved:
            self._episode(episode, now).truth.update(moved)
            self._buffered += len(moved)

    def new_run(self) -> None:
        """The source restarted: its episode ids start again, so the scored ids are
        forgotten. Unscored episodes stay: the old run's last finals may still be on their
        way; each is scored as usual, or replaced when the new run's EpisodeInfo for its id
        comes, or dropped after ``forget_after``."""
        self._scored.clear()

    def _remember(self, episode: int, ep: OpenEpisode) -> None:
        self._scored[episode] = ScoredEpisode(ep.window, ep.started_ns)
        self._scored.move_to_end(episode)
        while len(self._scored) > self.config.max_scored_episodes:
            self._scored.popitem(last=False)

    # --- scoring --------------------------------------------------------------------------
    @staticmethod
    def _complete(ep: OpenEpisode, truth: Iterable[Key]) -> bool:
        """Whether ``truth`` (keys inside the window) holds every ENDED count."""
        if ep.counts is None:
            return False
        have = Counter(key[0] for key in truth)
        return all(have[sensor] >= n for sensor, n in ep.counts.items())

    def _try(self, episode: int) -> None:
        ep = self._open[episode]
        if (
            ep.final is not None
            and ep.counts is not None
            and len(ep.truth) >= sum(ep.counts.values())  # cheap, before the full count
            and self._complete(ep, [k for k in ep.truth if ep.inside(k[1])])
        ):
            self._score(episode)

    def _score(self, episode: int) -> None:
        ep = self._open.pop(episode)
        self._buffered -= len(ep.truth)
        truth = {k: v for k, v in ep.truth.items() if ep.inside(k[1])}
        tracks = ep.final
        complete = self._complete(ep, truth)
        self._remember(episode, ep)
        ids, stamps, _, labels = conv.tracks_from_msg(tracks)
        lanes, _ = conv.track_lanes_from_msg(tracks)
        track_of = dict(zip(zip(ids.tolist(), stamps.tolist(), lanes.tolist()), labels.tolist()))
        keys = list(truth)
        index = self._sensor_index
        values = list(truth.values())
        detections = Detections(
            np.array([index(k[0]) for k in keys], dtype=np.int64),
            conv.ns_to_seconds([k[1] for k in keys]),
            np.array([v[1] for v in values], dtype=float),
            np.array([v[0] for v in values], dtype=np.int64),
        )
        result = score(detections, np.array([track_of.get(k, -1) for k in keys], np.int64))
        expected = 'unknown' if ep.counts is None else str(sum(ep.counts.values()))
        if result.total == 0:
            # no true detection at hand: there is no accuracy to publish
            self.events['episodes_unscored'] += 1
            self._node.get_logger().warning(
                f'episode {episode} [{tracks.method}]: not scored, no true detection at hand '
                f'({len(truth)} of {expected} ground-truth messages, '
                f'{"all" if complete else "truth incomplete"}); nothing published'
            )
            return
        accuracy = result.accuracy
        if complete:
            self.sum += accuracy
            self.in_mean += 1
        else:
            self.incomplete += 1
        mean = self.sum / self.in_mean if self.in_mean else 0.0
        msg = conv.score_to_msg(
            episode_id=episode,
            method=tracks.method,
            score=result,
            mean_accuracy=mean,
            episodes_scored=self.in_mean,
            stamp_ns=self._node.get_clock().now().nanoseconds,
        )
        msg.truth_complete = complete
        msg.truth_expected = 0 if ep.counts is None else sum(ep.counts.values())
        msg.truth_received = len(truth)
        msg.episodes_incomplete = self.incomplete
        self._score_pub.publish(msg)
        note = (
            '' if complete else f' [truth incomplete: {len(truth)} of {expected}; not in the mean]'
        )
        mean_text = f'{mean:.4f}' if self.in_mean else 'none yet'
        self._node.get_logger().info(
            f'episode {episode} [{tracks.method}]: accuracy {accuracy:.4f} '
            f'({result.correct}/{result.total}), link P/R {result.link_precision:.4f}/'
            f'{result.link_recall:.4f}, id switches {result.identity_switches}, '
            f'ARI {result.adjusted_rand_index:.4f}; mean accuracy {mean_text} over '
            f'{self.in_mean} episode(s){note}'
        )
