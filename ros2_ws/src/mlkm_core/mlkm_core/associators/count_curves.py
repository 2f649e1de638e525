"""Travel times from the stations' cumulative counts: the extra time of a queue as it changes.

Between two stations with no entry and no exit, every vehicle that passes the upstream
station passes the downstream one (conservation). In a lane that nobody can leave, the k-th
vehicle upstream is the (k + o)-th downstream, o the vehicles already between the stations
when the record starts; on several lanes vehicles pass one another, but only by a few places.
So the horizontal distance between the two stations' cumulative count curves (Newell's
N-curves) is the travel time of the vehicles entering the gap at that moment, whatever the
queue between does: it grows as the queue builds and shrinks as it clears. The speeds
measured at the two stations predict a travel time too (``motion.trapezoid_residual``);
what they miss, over the vehicles paired by their counts and smoothed over their neighbours,
is the gap's extra time as a function of the time of entry (``gap_delays.GapProfile``).
Estimated from the detections being associated, with no tracks and no model of the queue.

``o`` is the number of downstream detections before the first upstream vehicle could have
arrived at the highest speed seen. A missed detection or a false alarm shifts the pairing by
one place from there on, so gaps whose two counts differ by more than a few per cent are
left out, as are gaps with an entry or an exit between their stations.

:func:`with_count_curves` gives a gap its count curves' extra time where the data show that
the first pass's does not fit, in one of two ways:

* the holdup changes with time: the count-paired travel times are clearly narrower about
  the profile than about their median, the first pass left a part of the gap's vehicles
  unlinked, and the profile links at least as many of them; the gap gets the profile;
* the first pass linked the gap whole vehicles off (``shifted_gaps``): where every vehicle
  is held up alike and they follow one another a headway apart, a pass that starts with the
  wrong extra time links each vehicle to one a place or two ahead, its links' residuals are
  as consistent with that extra time as the true ones would be, and every later estimate
  from its links keeps it; the gap's count-paired vehicles sit at another level, more
  consistently than the pass's links sit at theirs. The gap gets the count curves' level
  (a constant: the counts pair its vehicles to within less than a place).

Elsewhere (free flow, or a gap the speeds already explain) nothing changes.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from mlkm_core.associators.delays import gap_links, robust_location
from mlkm_core.associators.linking import link, relabel
from mlkm_core.model.gap_delays import GapDelays, GapProfile
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout, link_pairs

#: vehicles over which the travel time of the count-paired vehicles is smoothed (a running
#: median: the few places by which vehicles on several lanes pass one another drop out)
WINDOW = 15
#: fewest detections at each end of a gap: three smoothing windows, so that the profile is
#: more than its two ends (a stream window's few dozen vehicles per station are not enough)
MIN_COUNT = 3 * WINDOW
#: largest difference of a gap's two counts, as a fraction of the larger (missed detections,
#: false alarms and the vehicles inside the gap at the record's two ends)
COUNT_MISMATCH = 0.05
#: quantile of the speeds taken as the highest (the first vehicle's fastest arrival) [-]
FAST_QUANTILE = 0.99
#: the count-paired travel times must be this many times narrower (robust spread) about the
#: profile than about their median for the holdup to count as changing with time [-]
PROFILE_RATIO = 1.5
#: ... and the first pass must have linked fewer than this fraction of the gap's vehicles
#: (the smaller of its two counts): where it links them all, a constant extra time fits [-]
LINKED = 0.95
#: a first pass's links sit whole vehicles off the counts where their median travel-time
#: residual differs from the count-paired vehicles' by more than this share of the gap's
#: headway (the median at its downstream station) [-]
SHIFT = 0.5
#: links of a pass across a gap needed to judge where they sit
MIN_SHIFT_LINKS = 20


def conserving_gaps(n_sensors: int, openings: tuple[np.ndarray, np.ndarray] | None) -> list:
    """Gaps (index of the upstream station) with no entry and no exit between their stations
    (``openings``: ``MotionParams.road_openings``; None: a closed road)."""
    gaps = np.arange(max(n_sensors - 1, 0))
    if openings is not None:
        first, last = openings
        # an entry right before station g + 1 makes it the first a new track may have passed;
        # an exit right after station g makes g the last one a track may pass before leaving
        gaps = gaps[(first[gaps + 1] <= gaps) & (last[gaps] >= gaps + 1)]
    return [int(g) for g in gaps]


def running_median(x: np.ndarray, window: int) -> np.ndarray:
    """Median of each element and its ``window // 2`` neighbours on either side (fewer at
    the ends)."""
    half, n = window // 2, x.size
    out = np.empty(n)
    if n > 2 * half:
        out[half : n - half] = np.median(sliding_window_view(x, 2 * half + 1), axis=1)
    for i in (*range(min(half, n)), *range(max(n - half, min(half, n)), n)):
        out[i] = np.median(x[max(i - half, 0) : i + half + 1])
    return out


def robust_spread(x: np.ndarray) -> float:
    """1.4826 median absolute deviation from the median (``delays.robust_location``)."""
    return float(np.sqrt(robust_location(x)[1]))


def count_pairs(
    layout: Layout, d: Detections, g: int, fastest: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Detections (upstream, downstream) of gap ``g`` paired by their counts, in time order,
    the first upstream vehicle at most at speed ``fastest`` [m/s]; None where the counts do
    not conserve."""
    a = np.flatnonzero(d.sensor_index == g)
    b = np.flatnonzero(d.sensor_index == g + 1)
    if min(a.size, b.size) < MIN_COUNT:
        return None
    if abs(a.size - b.size) > COUNT_MISMATCH * max(a.size, b.size):
        return None
    a, b = a[np.argsort(d.stamp[a], kind='stable')], b[np.argsort(d.stamp[b], kind='stable')]
    dx = layout.positions[g + 1] - layout.positions[g]
    offset = int(np.sum(d.stamp[b] < d.stamp[a[0]] + dx / fastest))
    n = min(a.size, b.size - offset)
    if n < MIN_COUNT:
        return None
    return a[:n], b[offset : offset + n]


def count_curve_profiles(
    layout: Layout,
    d: Detections,
    openings: tuple[np.ndarray, np.ndarray] | None = None,
    gaps: list[int] | None = None,
) -> dict[int, tuple[float, GapProfile, float]]:
    """Per conserving gap (of ``gaps``, default all): (the extra time's median [s], its
    profile about the median, how many times narrower the count-paired travel times are about
    the profile than about their median)."""
    out: dict[int, tuple[float, GapProfile, float]] = {}
    pos, u = layout.positions, 1.0 / d.velocity
    fastest = float(np.quantile(d.velocity, FAST_QUANTILE)) if len(d) else 0.0
    for g in conserving_gaps(layout.n_sensors, openings):
        if gaps is not None and g not in gaps:
            continue
        pairs = count_pairs(layout, d, g, fastest)
        if pairs is None:
            continue
        a, b = pairs
        e = _residuals(d, u, pos[g + 1] - pos[g], a, b)
        smooth = running_median(e, WINDOW)
        level = float(np.median(smooth))
        ratio = robust_spread(e) / max(robust_spread(e - smooth), 1e-3)
        out[g] = (level, GapProfile(g, d.stamp[a].astype(float), smooth - level), ratio)
    return out


def shifted_gaps(
    layout: Layout,
    d: Detections,
    labels: np.ndarray,
    openings: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[int, float]:
    """Per gap whose links in ``labels`` sit whole vehicles off its counts: the count-paired
    vehicles' extra time [s] (the median of their travel-time residuals).

    A gap qualifies where its conserving counts pair its vehicles (``count_pairs``) to within
    less than a place, and more consistently than the links do: the count-paired residuals'
    robust spread about their running median is below the gap's headway and below the links'
    own robust spread; and where the two medians differ by more than ``SHIFT`` headways.
    A pass linked one place off has residuals of the right size but the wrong level; on
    several lanes, where vehicles pass one another, the count pairs scatter more than right
    links do, so a pass that links the gap right is left alone."""
    out: dict[int, float] = {}
    pos, u = layout.positions, 1.0 / d.velocity
    fastest = float(np.quantile(d.velocity, FAST_QUANTILE)) if len(d) else 0.0
    a, b = link_pairs(d, labels)
    for g in conserving_gaps(layout.n_sensors, openings):
        k = (d.sensor_index[a] == g) & (d.sensor_index[b] == g + 1)
        pairs = count_pairs(layout, d, g, fastest)
        if pairs is None or k.sum() < MIN_SHIFT_LINKS:
            continue
        dx = pos[g + 1] - pos[g]
        counted = _residuals(d, u, dx, *pairs)
        linked = _residuals(d, u, dx, a[k], b[k])
        downstream = np.sort(d.stamp[d.sensor_index == g + 1])
        headway = float(np.median(np.diff(downstream)))
        spread = robust_spread(counted - running_median(counted, WINDOW))
        level = float(np.median(counted))
        if spread >= min(headway, robust_spread(linked)):
            continue
        if abs(level - float(np.median(linked))) > SHIFT * headway:
            out[g] = level
    return out


def _residuals(d: Detections, u: np.ndarray, dx: float, a: np.ndarray, b: np.ndarray):
    """Travel time from ``a`` to ``b`` beyond the trapezoid of their speeds [s]."""
    return d.stamp[b] - d.stamp[a] - dx * (u[a] + u[b]) / 2


def with_count_curves(
    layout: Layout,
    d: Detections,
    base: MotionParams,
    raw: np.ndarray,
    openings: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[MotionParams, np.ndarray]:
    """``base`` (without delays) and its first pass's tracks ``raw``; returns them with the
    count curves' extra time in the gaps where the first pass's does not fit (see the module
    docstring), and the tracks of a pass with it; unchanged where no gap qualifies."""
    n = layout.n_sensors
    labels = relabel(raw)
    before = gap_links(layout, d, labels)
    count = np.bincount(d.sensor_index, minlength=n)
    unlinked = [g for g in range(n - 1) if before[g] < LINKED * min(count[g], count[g + 1])]
    found = {
        g: f
        for g, f in count_curve_profiles(layout, d, openings, unlinked).items()
        if f[2] >= PROFILE_RATIO
    }
    # a shifted gap keeps its counts' constant level whatever the links count (a pass one
    # place off links as many vehicles as the right one), unless it keeps their profile
    shifted = shifted_gaps(layout, d, labels, openings)
    if not found and not shifted:
        return base, raw

    def delays(gaps: list[int]) -> GapDelays:
        level = np.zeros(n - 1)
        for g, x in shifted.items():
            level[g] = x
        for g in gaps:
            level[g] = found[g][0]
        return GapDelays.per_gap(
            layout.positions, level, np.zeros(n - 1), tuple(found[g][1] for g in gaps)
        )

    trial = link(layout, d, replace(base, delay=delays(list(found))), 'pairwise')
    after = gap_links(layout, d, relabel(trial))
    keep = [g for g in found if after[g] >= before[g]]
    if not keep and not shifted:
        return base, raw
    if len(keep) == len(found):
        return replace(base, delay=delays(keep)), trial
    p = replace(base, delay=delays(keep))
    return p, link(layout, d, p, 'pairwise')


def beside(delay: GapDelays | None, counted: GapDelays | None) -> GapDelays | None:
    """``delay`` (constant extra times) in the gaps that have none from the count curves
    (``counted``: a profile, or a level of a shifted gap), whose profiles are kept."""
    if delay is None or counted is None:
        return delay
    own = counted.gap_time != 0
    own[[prof.gap for prof in counted.profiles]] = True
    mean = np.where(own, counted.gap_time, delay.gap_time)
    return GapDelays.per_gap(delay.positions, mean, np.zeros_like(mean), counted.profiles)
