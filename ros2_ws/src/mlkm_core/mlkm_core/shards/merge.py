"""One view of every shard's tracks (ROS-free; the ``track_merge`` node around it).

Each shard publishes the tracks of its own stations under ids that name it
(:func:`~mlkm_core.shards.regions.shard_track_id`), and on the hand-off topic which upstream
track each of its tracks continues. The merge follows those continuations back to the track
that began most upstream and publishes one track under that id: the union of the pieces,
ordered by position. A piece published on its own before its continuation was known is
retired (published once more with no detection, FINAL) when it joins its upstream track.

Status: FINAL once every piece is in and FINAL and no continuation can still come. A
continuation may overtake the TrackArray of the piece it names (two topics, either order):
that piece is waited for, unless its shard's run ended. Each piece's shard has settled past
the piece's newest detection (so the offers and continuations that name the piece are in),
and the last piece was not offered downstream, or the next shard's ``settled_until`` passed
its offered detection by the hand-off horizon (an offer no shard accepts ends the track
there, as an exit would), or the next shard settled everything it took. Otherwise CONFIRMED
once any piece is, else TENTATIVE.

``committed_until`` is the earliest, over the shards, of what each one committed and
settled; nothing before every shard has reported. A shard that settled everything it took (a
quiet road it flushed) holds nothing back; when all have, it is the newest stamp of all. A
shard whose run changes (it restarted) ended its earlier run's pieces: they count as FINAL
with the detections they last carried.

Rows are opaque tuples whose second element is the stamp [ns] and fourth the position [m]
(the rows of ``mlkm_assoc.stream_state``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mlkm_core.shards.regions import MAX_SHARDS

TENTATIVE, CONFIRMED, FINAL = 0, 1, 2
NS_PER_S = 1_000_000_000


@dataclass
class Piece:
    shard: int
    run: int
    status: int
    rows: list[tuple]


@dataclass
class MergeOut:
    """What to publish: changed tracks (id, status, rows), unassigned rows, and the
    merged commit time [s] (-inf while some shard has not reported)."""

    tracks: list[tuple[int, int, list[tuple]]] = field(default_factory=list)
    unassigned: list[tuple] = field(default_factory=list)
    committed_until: float = -math.inf

    def __bool__(self) -> bool:
        return bool(self.tracks or self.unassigned)


class TrackMerge:
    """Pieces of ``count`` shards joined into one set of tracks."""

    def __init__(self, count: int, horizon: float) -> None:
        if not 1 <= count <= MAX_SHARDS:
            raise ValueError(f'shard count must be in 1..{MAX_SHARDS}, got {count}')
        self.count = count
        self.horizon = float(horizon)
        self._pieces: dict[int, Piece] = {}
        self._parent: dict[int, int] = {}  # piece -> the upstream piece it continues
        self._child: dict[int, int] = {}
        self._continued_in: dict[int, int] = {}  # piece -> the run of its shard that said so
        self._offered: dict[int, float] = {}  # piece -> its latest offered stamp [s]
        self._shown: set[int] = set()  # ids published with detections, not yet FINAL
        self._status_out: dict[int, int] = {}  # the status each id was last published with
        self._runs: list[int | None] = [None] * count
        self._until = [-math.inf] * count  # tracks' committed_until per shard [s]
        self._settled = [-math.inf] * count  # hand-off's settled_until per shard [s]
        self._newest = [-math.inf] * count  # newest stamp each shard took [s]
        self.retired = 0  # pieces that joined an upstream track after they were published
        self.continued = 0  # continuations taken

    # --- inputs ---------------------------------------------------------------------------
    def add_tracks(
        self,
        shard: int,
        run: int,
        tracks: list[tuple[int, int, list[tuple]]],
        unassigned: list[tuple],
        committed_until: float,
    ) -> MergeOut:
        """A shard's TrackArray: (id, status, rows) per changed track."""
        touched = self._run(shard, run)
        ended = run < (self._runs[shard] or 0)  # a late message of an earlier run
        for track_id, status, rows in tracks:
            self._pieces[track_id] = Piece(shard, run, FINAL if ended else status, list(rows))
            touched.add(track_id)
        self._until[shard] = max(self._until[shard], committed_until)
        return self._out(touched, list(unassigned))

    def add_handoff(
        self,
        shard: int,
        run: int,
        offers: list[tuple[int, float]],
        continuations: list[tuple[int, int]],
        settled_until: float,
        newest: float,
    ) -> MergeOut:
        """A shard's hand-off: offered (track id, stamp [s]), continuations (upstream id,
        its id), its settled time and the newest stamp it took [s]."""
        touched = self._run(shard, run)
        retire = []
        for track_id, stamp in offers:
            self._offered[track_id] = max(self._offered.get(track_id, -math.inf), stamp)
        for up, here in continuations:
            if up in self._child or here in self._parent:
                continue  # each piece continues at most one, and is continued at most once
            self._parent[here], self._child[up] = up, here
            self._continued_in[here] = run
            self.continued += 1
            if here in self._shown:
                retire.append(here)
            touched.update((up, here))
        self._settled[shard] = max(self._settled[shard], settled_until)
        self._newest[shard] = max(self._newest[shard], newest)
        # offered tracks waiting on this shard, and this shard's tracks waiting for it to
        # settle, may be final now: published again only when their status changed
        recheck = {t for t in self._offered if self._shard(t) + 1 == shard}
        recheck.update(
            t for t, p in self._pieces.items() if p.shard == shard and p.status == FINAL
        )
        out = self._out(touched, [], recheck)
        for here in retire:
            self._shown.discard(here)
            self.retired += 1
            out.tracks.append((here, FINAL, []))
        return out

    # --- the view ---------------------------------------------------------------------------
    def root(self, track_id: int) -> int:
        seen = set()
        while track_id in self._parent and track_id not in seen:
            seen.add(track_id)
            track_id = self._parent[track_id]
        return track_id

    @property
    def committed_until(self) -> float:
        if any(r is None for r in self._runs):
            return -math.inf
        bounds = [
            math.inf if self._caught_up(k) else min(self._until[k], self._settled[k])
            for k in range(self.count)
        ]
        low = min(bounds)
        # all caught up: every detection seen is committed, the newest one included
        return max(self._newest) + 1e-9 if low == math.inf else low

    def _settled_past(self, piece: Piece) -> bool:
        """The piece's shard settled past its newest detection, or the piece is of a run
        the shard ended."""
        if piece.run != self._runs[piece.shard] or not piece.rows:
            return True
        return self._settled[piece.shard] >= max(r[1] for r in piece.rows) / NS_PER_S

    def _caught_up(self, shard: int) -> bool:
        """The shard committed and settled everything it took (a flushed quiet road)."""
        newest = self._newest[shard]
        return newest > -math.inf and min(self._until[shard], self._settled[shard]) >= newest

    def _chain(self, root: int) -> list[int]:
        chain = [root]
        while chain[-1] in self._child and len(chain) <= self.count:
            chain.append(self._child[chain[-1]])
        return chain

    def _awaited(self, track_id: int) -> bool:
        """A continuation named the piece, whose TrackArray has not come yet: its shard
        publishes it before the hand-off, but on another topic, so it may arrive later (it
        never will once that shard's run ended)."""
        run = self._continued_in.get(track_id)
        return run is not None and run == self._runs[self._shard(track_id)]

    def _status(self, ids: list[int], chain: list[Piece | None]) -> int:
        pieces = [p for p in chain if p is not None]
        if all(p.status == FINAL for p in pieces):
            if any(not self._settled_past(p) for p in pieces):
                return CONFIRMED  # an offer or a continuation naming it may be on its way
            if any(p is None and self._awaited(i) for i, p in zip(ids, chain, strict=True)):
                return CONFIRMED
            last = ids[-1]
            shard = self._shard(last)
            stamp = self._offered.get(last)
            if stamp is None or shard + 1 >= self.count:
                return FINAL
            if self._settled[shard + 1] > stamp + self.horizon or self._caught_up(shard + 1):
                return FINAL
            return CONFIRMED
        return CONFIRMED if any(p.status >= CONFIRMED for p in pieces) else TENTATIVE

    def _out(
        self, touched: set[int], unassigned: list[tuple], recheck: set[int] = frozenset()
    ) -> MergeOut:
        """The tracks of the ``touched`` pieces (changed), and of the ``recheck`` ones whose
        status changed."""
        out = MergeOut(unassigned=unassigned, committed_until=self.committed_until)
        changed = {self.root(t) for t in touched}
        for root in sorted(changed | {self.root(t) for t in recheck}):
            ids = self._chain(root)
            pieces = [self._pieces.get(i) for i in ids]
            if all(p is None for p in pieces):
                continue  # only hand-off news of a piece not published yet
            status = self._status(ids, pieces)
            if root not in changed and self._status_out.get(root) == status:
                continue
            self._status_out[root] = status
            rows = sorted((r for p in pieces if p is not None for r in p.rows),
                          key=lambda r: (r[3], r[1]))  # fmt: skip
            out.tracks.append((root, status, rows))
            if status == FINAL:
                self._forget(ids)
            elif rows:
                self._shown.add(root)
        return out

    def _forget(self, ids: list[int]) -> None:
        for i in ids:
            self._pieces.pop(i, None)
            self._offered.pop(i, None)
            self._shown.discard(i)
            self._status_out.pop(i, None)
            self._continued_in.pop(i, None)
            up = self._parent.pop(i, None)
            if up is not None:
                self._child.pop(up, None)
            down = self._child.pop(i, None)
            if down is not None:
                self._parent.pop(down, None)

    def _run(self, shard: int, run: int) -> set[int]:
        """The shard's run; a later one ends the pieces of the earlier (returned, touched)."""
        if not 0 <= shard < self.count:
            raise ValueError(f'shard {shard} is not one of 0..{self.count - 1}')
        old = self._runs[shard]
        if old is not None and run <= old:
            return set()
        self._runs[shard] = run  # its commit times carry on: the view's never go back
        ended = set()
        for track_id, p in self._pieces.items():
            if p.shard == shard and p.run < run and p.status != FINAL:
                p.status = FINAL
                ended.add(track_id)
        return ended

    @staticmethod
    def _shard(track_id: int) -> int:
        return track_id % MAX_SHARDS
