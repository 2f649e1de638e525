"""Extra travel time of the gaps between stations: what the speeds at a gap's ends do not show.

A queue or road works between two stations holds every vehicle up by about the same time,
give or take the stop-and-go waves: per gap a mean [s] and a variance [s^2]. Where the
holdup changes with time (a queue that grows and clears), a gap may also carry a *profile*:
how the extra time moves about the gap's mean with the time a vehicle enters the gap,
estimated from the stations' cumulative counts (``associators.count_curves``). A link that
crosses such a gap forward adds the profile's value at its upstream stamp to the gap's mean.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GapProfile:
    """How the extra time of gap ``gap`` departs from the gap's mean, against the time a
    vehicle passes its upstream station: piecewise linear through (``times`` [s], ``extra``
    [s]), constant beyond the ends."""

    gap: int
    times: np.ndarray  # increasing [s]
    extra: np.ndarray  # [s]

    def at(self, t: float | np.ndarray) -> float | np.ndarray:
        return np.interp(t, self.times, self.extra)


@dataclass(frozen=True)
class GapDelays:
    """Extra travel time of the gaps between consecutive sensors, beyond what the speeds at
    their ends predict: per gap a mean [s] and a variance [s^2], kept as sums from the first
    sensor so that a link over several gaps adds up the gaps it crosses; per gap with a
    ``GapProfile`` also its departure from the mean at the link's upstream stamp.
    """

    positions: np.ndarray  # sensor positions along the road [m], increasing
    time: np.ndarray  # extra time from the first sensor to each sensor [s]
    var: np.ndarray  # variance of that extra time [s^2]
    # gaps where the extra time depends on the lane at the gap's first sensor (a lane that ends
    # at a merge): (gap, lane, extra time [s], its variance [s^2]) of each such lane, used
    # instead of the gap's own for the links out of that lane (``merges.relink_lane_delays``)
    lanes: tuple[tuple[int, int, float, float], ...] = ()
    # gaps where a car of a continuing lane that passes the next sensor right behind a car of a
    # closing lane (it let that car in) is held up more: (gap, extra time [s], variance [s^2])
    # (``merges.exchange_merge_order``)
    yields: tuple[tuple[int, float, float], ...] = ()
    # gaps whose extra time changes with the time of entry (``count_curves``)
    profiles: tuple[GapProfile, ...] = ()

    @classmethod
    def per_gap(
        cls,
        positions: np.ndarray,
        mean: np.ndarray,
        var: np.ndarray,
        profiles: tuple[GapProfile, ...] = (),
    ) -> GapDelays:
        """From the mean [s] and variance [s^2] of each of the n - 1 gaps."""
        return cls(
            np.asarray(positions, float).copy(),
            np.concatenate([[0.0], np.cumsum(mean)]),
            np.concatenate([[0.0], np.cumsum(var)]),
            profiles=profiles,
        )

    @property
    def gap_time(self) -> np.ndarray:
        """Mean extra time of each gap [s]."""
        return np.diff(self.time)

    @property
    def gap_var(self) -> np.ndarray:
        """Variance of each gap's extra time [s^2]."""
        return np.diff(self.var)

    def _between(self, cum: np.ndarray, x1, x2):
        top = self.positions.size - 1
        k1 = np.clip(np.searchsorted(self.positions, x1, side='right') - 1, 0, top)
        k2 = np.clip(np.searchsorted(self.positions, x2, side='right') - 1, 0, top)
        return cum[k2] - cum[k1]

    def extra_time(
        self,
        x1: float | np.ndarray,
        x2: float | np.ndarray,
        t1: float | np.ndarray | None = None,
    ) -> float | np.ndarray:
        """Mean extra time [s] from x1 to x2 (negative for x2 < x1); with ``t1``, the stamp
        at x1 [s], a forward link adds the profiles of the gaps it crosses at ``t1``."""
        out = self._between(self.time, x1, x2)
        if not self.profiles or t1 is None:
            return out
        for prof in self.profiles:
            lo, hi = self.positions[prof.gap], self.positions[prof.gap + 1]
            crossed = (np.asarray(x1) <= lo) & (np.asarray(x2) >= hi)
            if np.any(crossed):
                out = out + np.where(crossed, prof.at(t1), 0.0)
        return out

    def extra_var(self, x1: float | np.ndarray, x2: float | np.ndarray) -> float | np.ndarray:
        """Variance [s^2] of the extra time between x1 and x2, in either direction."""
        return np.abs(self._between(self.var, x1, x2))

    def with_gap(self, gap: int, mean: float, var: float) -> GapDelays:
        """The same delays with gap ``gap``'s mean [s] and variance [s^2] replaced (and its
        profile dropped)."""
        t, v = self.gap_time.copy(), self.gap_var.copy()
        t[gap], v[gap] = mean, var
        kept = tuple(p for p in self.profiles if p.gap != gap)
        return GapDelays.per_gap(self.positions, t, v, kept)

    def mirrored(self) -> GapDelays:
        """The same delays on the road seen backwards (positions negated and reversed), without
        those of lanes, merges and profiles (a backward link does not know the lane it will
        leave from, nor when it entered the gap)."""
        return GapDelays(
            -self.positions[::-1], self.time[-1] - self.time[::-1], self.var[-1] - self.var[::-1]
        )
