"""The immediate link of the stream tracker: each detection joins a track the moment it is
pushed, by the gated pairwise prediction (mechanism, step 1, in ``mlkm_core.streaming``)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from mlkm_core.model.motion import MotionParams
from mlkm_core.streaming.book import Det
from mlkm_core.streaming.config import StreamConfig
from mlkm_core.streaming.motion import LinkCost
from mlkm_core.streaming.revise import Revisions
from mlkm_core.types import Layout


class ImmediateLinks(Revisions):
    """The road's entries and exits, the motion parameters of the moment and the immediate
    link of a detection to an open track."""

    def __init__(
        self,
        layout: Layout,
        config: StreamConfig,
        entries: Sequence[float],
        exits: Sequence[float],
    ) -> None:
        super().__init__(layout.n_sensors, config.confirm_count)
        self.layout = layout
        self.config = config
        pos = layout.positions
        n_s = layout.n_sensors
        # a station right after an on-ramp (or the first) may see births; a station right
        # before an off-ramp may be the last one a vehicle passes
        self._after_entry = np.zeros(n_s, bool)
        self._after_entry[0] = True
        self._before_exit = np.zeros(n_s, bool)
        self._before_exit[-1] = True
        for name, values in (('entries', entries), ('exits', exits)):
            for x in values:
                if not math.isfinite(float(x)):
                    raise ValueError(f'{name} positions must be finite, got {x!r}')
        for x in entries:
            s = int(np.searchsorted(pos, float(x)))
            if s < n_s:
                self._after_entry[s] = True
        for x in exits:
            s = int(np.searchsorted(pos, float(x))) - 1
            if s >= 0:
                self._before_exit[s] = True
        self._params = MotionParams()
        self._cost: LinkCost | None = None  # the immediate link's cost under _params

    def _link_cost(self) -> LinkCost:
        """The pairwise model's link cost under the current motion parameters."""
        if self._cost is None or self._cost.p is not self._params:
            self._cost = LinkCost(self._params, self.layout)
        return self._cost

    def _tail_due(self, tail: Det) -> float:
        """A tail takes no new detection once every station it could be linked to (1 to
        1 + max_skip on) is past the gate, and it is older than the stamp noise's gate
        before any new one (the downstream candidates of ``_link_now``); computed with the
        parameters of the moment."""
        p = self._params
        late = tail.stamp + 6 * math.sqrt(2) * p.stamp_noise
        to = min(tail.sensor + 1 + p.max_skip, self.layout.n_sensors - 1)
        if to == tail.sensor:
            return late
        return max(late, self._link_cost().due((tail.sensor, tail.stamp, tail.velocity), to))

    def _link_now(self, d: Det) -> tuple[int, int]:
        """(track, key of the detection ``d`` follows in it) by the gated pairwise prediction,
        or (-1, -1) for a new track. Candidates: the open tracks whose latest detection lies
        1 to 1 + max_skip stations upstream, and those whose latest detection lies up to that
        far downstream but that have no detection at d's station (stamps out of road order
        under noise, or a miss filled in; not one that passed there more than the stamp
        noise's gate before d), predicted from their detection just upstream."""
        p = self._params
        weight = self._link_cost().weight
        self._sleep_tails(self._newest - self.config.reorder_tolerance)
        s = d.sensor
        earliest = d.stamp - 6 * math.sqrt(2) * p.stamp_noise
        birth = p.miss_cost if self._after_entry[s] else p.new_cost
        best, best_w = (-1, -1), 0.0
        dets = self._dets
        for j in range(max(0, s - 1 - p.max_skip), min(self.layout.n_sensors, s + 2 + p.max_skip)):
            if j == s:
                continue
            for tid in self._tails[j]:
                tail = dets[self._tail_of[tid][0]]
                if j < s:
                    if tail.stamp >= d.stamp:
                        continue
                else:
                    if tail.stamp < earliest:
                        continue
                    members = [dets[k] for k in self._tracks[tid]]
                    if any(m.sensor == s for m in members):
                        continue
                    up = [m for m in members if m.sensor < s]
                    if not up:
                        continue
                    tail = max(up, key=lambda m: (m.sensor, m.stamp))
                w = weight((tail.sensor, tail.stamp, tail.velocity), s, d.stamp, d.velocity, birth)
                if w < best_w:  # the cheapest (the first of equals), if cheaper than none
                    best, best_w = (tid, tail.key), w
        return best
