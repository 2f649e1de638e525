"""Fixed-time traffic signals, learned from the links of a pass: who waits for which green.

A vehicle that reaches a signalised stop line on red waits for the next green of its
movement, behind the vehicles queued before it; one that arrives on green and finds no queue
goes through. A single Gaussian time lost per connection (``junctions``) cannot say that: it
spreads a 20-70 s wait over every vehicle alike. A fixed-time signal repeats with its cycle,
and the green of a movement is one window of it; both show in the times at which the
vehicles of a pass's links *leave* a junction (their first station after it, less the way
from the junction to that station at the speed measured there):

* **The cycle**, per group of connections that share a link (one junction, in effect): the
  period in ``CYCLE_RANGE`` whose phase concentrates those exit times most, summed over the
  group's connections (the Rayleigh statistic of each, on the links that cross that junction
  alone); learned only where exits at random times would concentrate as much at some period
  with a chance below ``CYCLE_CHANCE`` (a search over periods finds one in any data, and a
  stream window's few links at a diverge would otherwise show a signal).
* **The green** of each connection: the shortest window of the cycle holding ``GREEN_SHARE``
  of its exit phases, grown over the exits that follow on at its ends.
* **Whether it is a signal at all**: a connection keeps its green only where, on its links,
  the time lost is more concentrated once the wait for the green is taken off than without
  (the Gaussian log-likelihood of the central ``KEPT`` gains more than
  ``GAIN_PER_PARAMETER`` per window parameter). A priority junction, a yielding merge or a
  freeway diverge has no such window, and the cue weighs nothing there.
* **The queue** (``Approach``) of each link that leads to a signalised connection, at its
  last station: the vehicles seen there, in the order they reach the stop line, leave first
  in, first out, a headway apart, on the green of the link's connections pooled. The
  headway per lane is the one of ``HEADWAYS`` under which the waits predict the links' time
  lost best, or none where no queue predicts it better (``GAIN_PER_PARAMETER``).

A link's wait is then a function of when its vehicle, at the speed measured at its first
station, would reach the stop line (``Signals.wait``): its queue's release where the link
starts at the queue's station, then the time to the green of its own connection; over a hop
across several junctions the waits add up, the vehicle driving on at that speed between them.
The junction model's Gaussian keeps what is left (a slowing for a turn, the discharge's
irregularity). Everything is estimated from the data being associated; where a pass links
too many vehicles wrongly (a first pass across busy signals), the exit times of its links
show no window and no signal is learned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc.hops import Hops
from mlkm_core.types import Detections

#: periods [s] searched for a junction's cycle, and the step of the search
CYCLE_RANGE = (30.0, 180.0)
CYCLE_STEP = 0.1
#: largest chance that exits at random times show the cycle found, for it to be learned
#: (the search over the range of periods finds one in any data)
CYCLE_CHANCE = 0.01
#: share of a connection's exit phases its green window holds
GREEN_SHARE = 0.95
#: largest gap [s] between exit phases that still continues a green window
GREEN_GAP = 3.0
#: fewest links that crossed a connection (alone) to learn its green from
MIN_LINKS = 8
#: central share of the time lost that counts: for its mean and variance (``junctions``) and
#: where the model with and without the green are compared
KEPT = 0.95
#: least log-likelihood gain [nats] per parameter of a green window (start, length) to keep it
GAIN_PER_PARAMETER = 3.0
#: discharge headways [s per lane] among which the queue's is chosen (or none, where none
#: predicts the waits better)
HEADWAYS = (1.0, 1.5, 2.0, 2.5, 3.0)


@dataclass(frozen=True)
class Approach:
    """The queue before a signalised stop line: the last station of the link that leads to
    it, the way from that station to the stop line [m], the green of the link's pooled
    connections (cycle, start phase, length [s]) and the headway [s] at which its queue
    discharges."""

    station: int
    lead: float
    cycle: float
    start: float
    length: float
    headway: float

    def releases(self, stamp: np.ndarray, slowness: np.ndarray) -> np.ndarray:
        """When each vehicle seen at the station (``stamp`` [s], ``slowness`` [s/m]) may
        cross the stop line [s]: not before it reaches it, not before the vehicle ahead of it
        plus the headway (first in, first out), and on green."""
        reach = stamp + self.lead * slowness
        order = np.argsort(reach, kind='stable')
        out = np.empty(reach.size)
        prev = -np.inf
        for k in order.tolist():
            t = max(float(reach[k]), prev + self.headway)
            rel = (t - self.start) % self.cycle
            if rel > self.length:
                t += self.cycle - rel
            out[k] = prev = t
        return out


@dataclass(frozen=True)
class Signals:
    """Per connection ``(from link, to link)`` with a learned signal: the cycle [s] and the
    green window (start phase [s], length [s]); per link that leads to one: its queue
    (``Approach``); per hop that crosses one: the (connection, distance from the hop's first
    station to its stop line [m]) of each junction it crosses, in order, and its first
    station."""

    cycle: dict[tuple[int, int], float]
    green: dict[tuple[int, int], tuple[float, float]]
    approaches: dict[int, Approach]
    hops: dict[int, tuple[tuple[tuple[int, int], float], ...]]
    src: dict[int, int]  # per hop of ``hops``: its first station

    def releases(self, d: Detections) -> np.ndarray:
        """Per detection of ``d`` at the last station before a signal, when its queue lets
        it cross the stop line [s] (``Approach.releases``); NaN elsewhere."""
        out = np.full(len(d), np.nan)
        for a in self.approaches.values():
            at = np.flatnonzero(d.sensor_index == a.station)
            if at.size:
                out[at] = a.releases(d.stamp[at], 1.0 / d.velocity[at])
        return out

    def wait(
        self,
        hop: int,
        stamp: np.ndarray,
        slowness: np.ndarray,
        release: np.ndarray | None = None,
    ) -> np.ndarray:
        """Time [s] a vehicle seen at ``stamp`` [s] with ``slowness`` [s/m] at the first
        station of ``hop`` waits at its signals (0 where the hop crosses none); ``release``:
        its queue's release (``releases``) where known."""
        waited = np.zeros(np.shape(stamp))
        for k, (c, dist) in enumerate(self.hops.get(hop, ())):
            if c not in self.green:
                continue
            arrive = stamp + dist * slowness + waited
            a = self.approaches.get(c[0])
            if k == 0 and release is not None and a is not None and a.station == self.src[hop]:
                queued = np.where(np.isfinite(release), release, arrive)
                waited = waited + (np.maximum(queued, arrive) - arrive)
                arrive = np.maximum(queued, arrive)
            waited = waited + red_wait(arrive, self.cycle[c], *self.green[c])
        return waited

    def waits(
        self,
        hop: np.ndarray,
        stamp: np.ndarray,
        slowness: np.ndarray,
        release: np.ndarray | None = None,
    ) -> np.ndarray:
        """``wait`` of each row: a vehicle seen at ``stamp[k]`` with ``slowness[k]`` at the
        first station of hop ``hop[k]``, its queue's release ``release[k]`` where known."""
        out = np.zeros(hop.size)
        order = np.argsort(hop, kind='stable')
        keys, starts = np.unique(hop[order], return_index=True)
        ends = np.append(starts[1:], order.size)
        for h, lo, hi in zip(keys.tolist(), starts, ends, strict=True):
            if h in self.hops:
                rows = order[lo:hi]
                rel = None if release is None else release[rows]
                out[rows] = self.wait(h, stamp[rows], slowness[rows], rel)
        return out


def red_wait(arrive: np.ndarray, cycle: float, start: float, length: float) -> np.ndarray:
    """Wait [s] from ``arrive`` [s] to the next moment of the green window (``start`` phase,
    ``length`` [s]) of a signal of period ``cycle`` [s]: 0 inside it."""
    rel = np.mod(arrive - start, cycle)
    return np.where(rel <= length, 0.0, cycle - rel)


def hop_junctions(
    net: RoadNetwork, hops: Hops
) -> dict[int, tuple[tuple[tuple[int, int], float], ...]]:
    """Per hop that crosses a junction: (connection, distance [m] from its first station to
    the end of the link the connection leaves), in order."""
    lengths = net.link_lengths
    out = {}
    for h, turns in enumerate(hops.turns):
        if not turns:
            continue
        s = int(hops.src[h])
        dist = lengths[int(net.station_links[s])] - float(net.station_offsets[s])
        steps = []
        for k, c in enumerate(turns):
            if k:
                dist += lengths[turns[k - 1][1]]
            steps.append((c, dist))
        out[h] = tuple(steps)
    return out


def _groups(connections: list[tuple[int, int]]) -> list[list[tuple[int, int]]]:
    """Connections joined where they share a from link or a to link (one junction each)."""
    parent = list(range(len(connections)))

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    seen: dict[tuple[str, int], int] = {}
    for k, (a, b) in enumerate(connections):
        for key in (('from', a), ('to', b)):
            if key in seen:
                parent[root(k)] = root(seen[key])
            else:
                seen[key] = k
    out: dict[int, list[tuple[int, int]]] = {}
    for k, c in enumerate(connections):
        out.setdefault(root(k), []).append(c)
    return list(out.values())


def best_cycle(exits: list[np.ndarray]) -> tuple[float, float]:
    """(period [s], chance [-]): the period in ``CYCLE_RANGE`` that concentrates the phases of
    each array of ``exits`` [s] most (summed Rayleigh statistic |sum exp(2 pi i t / C)|^2 / n)
    and the chance that exits at random times would concentrate as much at some period of the
    range. Each array's statistic is about exponential with mean 1 for random times, so their
    sum over k arrays is Gamma(k); the search over the range tries about span x (1 / C_min -
    1 / C_max) independent periods, span the exits' time range."""
    periods = np.arange(CYCLE_RANGE[0], CYCLE_RANGE[1] + CYCLE_STEP / 2, CYCLE_STEP)
    score = np.zeros(periods.size)
    for t in exits:
        z = np.exp(2j * np.pi * (t[None, :] - t[0]) / periods[:, None]).sum(axis=1)
        score += np.abs(z) ** 2 / t.size
    best = int(np.argmax(score))
    span = max(float(t[-1] - t[0]) for t in exits)
    tries = max(span * (1.0 / CYCLE_RANGE[0] - 1.0 / CYCLE_RANGE[1]), 1.0)
    chance = min(_gamma_tail(float(score[best]), len(exits)) * tries, 1.0)
    return float(periods[best]), chance


def _gamma_tail(x: float, k: int) -> float:
    """P(X > x) for X ~ Gamma(k, 1), k a whole number: exp(-x) sum_{i < k} x^i / i!."""
    term, total = 1.0, 1.0
    for i in range(1, k):
        term *= x / i
        total += term
    return math.exp(-x) * total


def green_window(phases: np.ndarray, cycle: float) -> tuple[float, float]:
    """(start phase [s], length [s]) of the shortest window of the cycle holding
    ``GREEN_SHARE`` of ``phases`` [s, in [0, cycle)], grown at either end over the phases
    that follow on within ``GREEN_GAP`` (the last vehicles of a green are not outliers)."""
    ph = np.sort(phases)
    n = ph.size
    k = max(math.ceil(GREEN_SHARE * n), 1)
    ext = np.concatenate([ph - cycle, ph, ph + cycle])
    widths = ext[n + k - 1 : 2 * n + k - 1] - ext[n : 2 * n]
    lo = n + int(np.argmin(widths))
    hi = lo + k - 1
    while hi + 1 < lo + n and ext[hi + 1] - ext[hi] <= GREEN_GAP:
        hi += 1
    while lo - 1 > hi - n and ext[lo] - ext[lo - 1] <= GREEN_GAP:
        lo -= 1
    return float(ext[lo] % cycle), float(min(ext[hi] - ext[lo], cycle))


def central(x: np.ndarray) -> np.ndarray:
    """The central ``KEPT`` of ``x``, sorted (a pass's few wrong links are not waits)."""
    x = np.sort(x)
    cut = int((1.0 - KEPT) / 2 * x.size)
    return x[cut : x.size - cut]


def _central_nll(x: np.ndarray) -> float:
    """Gaussian NLL [nats] (up to a constant) of the central ``KEPT`` of ``x``."""
    mid = central(x)
    return 0.5 * mid.size * math.log(max(float(mid.var()), 1e-6))


def _ends(net: RoadNetwork, d: Detections, a: np.ndarray, b: np.ndarray):
    """Per link a -> b: when it would reach its first stop line at the speed of its first
    detection [s], and when it left the junction [s] (its second detection less the way from
    its link's start at the speed measured there)."""
    u = 1.0 / d.velocity
    lengths = net.link_lengths
    st_a, st_b = d.sensor_index[a], d.sensor_index[b]
    lead = np.array([lengths[int(k)] for k in net.station_links[st_a]]) - net.station_offsets[st_a]
    return d.stamp[a] + lead * u[a], d.stamp[b] - net.station_offsets[st_b] * u[b]


def fit_signals(
    net: RoadNetwork, hops: Hops, d: Detections, a: np.ndarray, b: np.ndarray, hop: np.ndarray,
    excess: np.ndarray,
) -> Signals | None:  # fmt: skip
    """The signals of the links ``a[k] -> b[k]`` (across ``hop[k]``) of a pass, from their
    travel-time excess [s] over the motion model's prediction (module docstring), without
    the time lost that is left (``junctions``). None where no connection shows a signal."""
    enter, leave = _ends(net, d, a, b)
    alone: dict[tuple[int, int], list[int]] = {}
    for k, h in enumerate(hop.tolist()):
        if len(hops.turns[h]) == 1:
            alone.setdefault(hops.turns[h][0], []).append(k)
    seen = [c for c, ks in alone.items() if len(ks) >= MIN_LINKS]
    cycle, green = {}, {}
    for group in _groups(seen):
        period, chance = best_cycle([np.sort(leave[alone[c]]) for c in group])
        if chance > CYCLE_CHANCE:
            continue  # exits at random times would show such a cycle: none is learned
        for c in group:
            ks = np.asarray(alone[c])
            window = green_window(np.mod(leave[ks], period), period)
            waited = red_wait(enter[ks], period, *window)
            gain = _central_nll(excess[ks]) - _central_nll(excess[ks] - waited)
            if gain > 2 * GAIN_PER_PARAMETER:
                cycle[c], green[c] = period, window
    if not green:
        return None
    along = hop_junctions(net, hops)
    used = {h: steps for h, steps in along.items() if any(c in green for c, _ in steps)}
    src = {h: int(hops.src[h]) for h in used}
    lengths = net.link_lengths
    pooled: dict[int, list[int]] = {}
    for c in green:
        pooled.setdefault(c[0], []).extend(alone[c])
    windows = {}
    for link, ks in pooled.items():
        if net.stations_along[link]:
            at, station = net.stations_along[link][-1]  # the queue's station: the last
            period = cycle[next(c for c in green if c[0] == link)]
            window = green_window(np.mod(leave[ks], period), period)
            windows[link] = (station, lengths[link] - at, period, *window)
    out = Signals(cycle, green, {}, used, src)
    best, best_score = out, _spread(out, d, a, hop, excess, alone)
    for per_lane in HEADWAYS:
        approaches = {
            link: Approach(*w, headway=per_lane / max(net.links[link].lanes, 1))
            for link, w in windows.items()
        }
        trial = replace(out, approaches=approaches)
        score = _spread(trial, d, a, hop, excess, alone)
        if score < best_score - GAIN_PER_PARAMETER:
            best, best_score = trial, score
    return best


def link_waits(signals: Signals, d: Detections, a: np.ndarray, hop: np.ndarray) -> np.ndarray:
    """The wait [s] at its signals of each link from detection ``a[k]`` across ``hop[k]``."""
    release = signals.releases(d)[a]
    return signals.waits(hop, d.stamp[a], 1.0 / d.velocity[a], release)


def _spread(
    signals: Signals, d: Detections, a: np.ndarray, hop: np.ndarray, excess: np.ndarray,
    alone: dict[tuple[int, int], list[int]],
) -> float:  # fmt: skip
    """Summed Gaussian NLL [nats] of the central share of each signalised connection's time
    lost once its links' waits are taken off (``_central_nll``): how well the waits
    predict."""
    r = excess - link_waits(signals, d, a, hop)
    return sum(_central_nll(r[ks]) for c, ks in alone.items() if c in signals.green)
