"""One shard's hand-off desk: the offers it makes downstream and the ones it accepts.

A shard's tracker also takes the upstream shard's last stations (its *margin*), so it links
a vehicle's margin detections to the vehicle's first detections in its own region with the
same model as any other link. The hand-off only has to say *which upstream track* those
margin detections belong to:

* **Offer.** When the shard commits a detection at one of the stations the next shard takes
  as its margin, it offers (its track id, the detection) downstream.
* **Accept.** When the shard commits the first detection of one of its tracks in its own
  region (no later than ``horizon`` after the track's margin detections), it looks at the
  track's margin detections, the most downstream first: the first one an upstream track
  offered, and whose track no other local track took, names the track it continues. A margin
  detection the upstream shard has not committed yet holds the decision back, so the choice
  depends on the detections alone, never on which message came first.
* **Settled.** Links of detections stamped before ``settled_until`` are committed *and* their
  track's continuation is decided: the shard's commit, held back to the first own detection
  of a track still waiting for an offer.

An offer no track accepts ends the upstream track where it is, as an exit would. Detections
are named by the contract's join key (``DetId``), the same in every shard.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

#: A detection's identity across processes: (sensor id, lane, stamp [ns], speed [m/s]).
DetId = tuple[int, int, int, float]
NS_PER_S = 1_000_000_000
#: A track's first own detection more than this after its margin detections starts anew;
#: also how long an offered track waits downstream before it is final [s].
DEFAULT_HORIZON = 60.0


def det_stamp(det: DetId) -> float:
    """The stamp of a detection identity [s]."""
    return det[2] / NS_PER_S


@dataclass
class DeskOutput:
    """What a batch of commits gave the desk: offers to send downstream (track id,
    detection) and continuations decided (upstream track id, local track id)."""

    offers: list[tuple[int, DetId]] = field(default_factory=list)
    accepts: list[tuple[int, int]] = field(default_factory=list)

    def __bool__(self) -> bool:
        return bool(self.offers or self.accepts)


class HandoffDesk:
    """The hand-off of one shard (ROS-free). ``margin_ids``: the sensor ids of the upstream
    margin with their road order (any increasing number); ``offered_ids``: the own stations
    the next shard takes as its margin; ``horizon`` in seconds."""

    def __init__(
        self,
        margin_ids: dict[int, int],
        offered_ids: Iterable[int],
        horizon: float = DEFAULT_HORIZON,
        after_ids: Iterable[int] = (),
    ) -> None:
        """``after_ids``: the next shard's stations this shard takes as evidence only (their
        detections are neither its own nor offered)."""
        if not horizon > 0:
            raise ValueError(f'the hand-off horizon must be positive, got {horizon}')
        self._order = dict(margin_ids)
        self._offered = frozenset(int(s) for s in offered_ids)
        self._after = frozenset(int(s) for s in after_ids)
        self.horizon = float(horizon)
        self._offers: dict[DetId, int] = {}  # margin detection -> upstream track
        self.upstream_until = -math.inf if self._order else math.inf  # [s]
        self.committed_until = -math.inf  # [s] this shard's
        self._margin_of: dict[int, list[DetId]] = {}  # local track -> its margin detections
        self._pending: dict[int, float] = {}  # local track -> its first own stamp [s]
        # local tracks decided and upstream tracks continued here, with the first own stamp
        # of the decision [s] (forgotten after two horizons)
        self._decided: dict[int, float] = {}
        self._taken: dict[int, float] = {}

    # --- inputs -------------------------------------------------------------------------
    def take_offers(self, offers: Iterable[tuple[int, DetId]], upstream_until: float) -> None:
        """Offers of the upstream shard and how far it has committed [s]."""
        for track, det in offers:
            self._offers[tuple(det)] = int(track)
        self.upstream_until = max(self.upstream_until, float(upstream_until))

    def commit(self, rows: Iterable[tuple[int, DetId]], committed_until: float) -> DeskOutput:
        """Committed links of this shard (local track id or -1, detection), and its new
        commit time [s]: the offers they make and the continuations now decided."""
        out = DeskOutput()
        for track, det in sorted(rows, key=lambda r: r[1][2]):
            sensor = det[0]
            if track < 0 or sensor in self._after:
                continue
            if sensor in self._order:
                self._margin_of.setdefault(track, []).append(det)
                continue
            if sensor in self._offered:
                out.offers.append((track, det))
            if track not in self._decided and track not in self._pending:
                self._pending[track] = det_stamp(det)
        self.committed_until = max(self.committed_until, float(committed_until))
        out.accepts = self.decide()
        self._prune()
        return out

    # --- decisions ------------------------------------------------------------------------
    def decide(self) -> list[tuple[int, int]]:
        """Decide every pending track whose margin detections are all committed upstream (or
        offered); (upstream track, local track) for those that continue one."""
        accepts = []
        for track, first in sorted(self._pending.items(), key=lambda kv: kv[1]):
            choice = self._choose(track, first)
            if choice is None:
                continue  # an offer may still come
            del self._pending[track]
            self._decided[track] = first
            self._margin_of.pop(track, None)
            if choice >= 0:
                self._taken[choice] = first
                accepts.append((choice, track))
        return accepts

    def _choose(self, track: int, first: float) -> int | None:
        """The upstream track ``track`` continues, -1 for none, None while undecided."""
        dets = [d for d in self._margin_of.get(track, ()) if first - det_stamp(d) <= self.horizon]
        dets.sort(key=lambda d: (self._order[d[0]], d[2]), reverse=True)
        for det in dets:
            up = self._offers.get(det)
            if up is not None:
                if up not in self._taken:
                    return up
            elif self.upstream_until <= det_stamp(det):
                return None
        return -1

    @property
    def settled_until(self) -> float:
        """Links stamped before this are committed and their continuation decided [s]."""
        if not self._pending:
            return self.committed_until
        return min(self.committed_until, min(self._pending.values()))

    @property
    def pending(self) -> int:
        return len(self._pending)

    def _prune(self) -> None:
        """Forget what no decision can need any more (memory stays bounded)."""
        old = min(self.committed_until, self.upstream_until) - 2 * self.horizon
        if not math.isfinite(old):
            return
        for det in [d for d in self._offers if det_stamp(d) < old]:
            del self._offers[det]
        for track in [t for t, ds in self._margin_of.items() if det_stamp(ds[-1]) < old]:
            del self._margin_of[track]
        for book in (self._decided, self._taken):
            for key in [k for k, first in book.items() if first < old]:
                del book[key]
