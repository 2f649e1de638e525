"""An endless simulated road: the simulator's traffic model (``mlkm_core.simulator``) with no
episodes, vehicles entering for ever, detections emitted in stamp order as a live source
publishes them (``sensor_sim`` in continuous mode, ``mlkm simulate --stream``)."""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from mlkm_core.simulator import SimConfig, _speed_profiles, _streams, make_layout
from mlkm_core.types import FALSE_ALARM, Layout

#: Vehicles generated ahead of the emitted passages; with U(-10, 30) s spacing a vehicle this
#: many places later enters before an earlier one with probability ~1e-13 (see simulate_stream).
STREAM_LOOKAHEAD = 64


class StreamDetection(NamedTuple):
    """One detection of an endless simulated road."""

    sensor_index: int  # index into the layout
    stamp: float  # passage time [s], >= 0
    velocity: float  # reported speed (with noise) [m/s]
    target: int  # vehicle number 0, 1, ... in entry order; FALSE_ALARM (-1) for clutter
    true_velocity: float  # speed before measurement noise [m/s]


def stream_layout(config: SimConfig, seed: int) -> Layout:
    """The road of ``simulate_stream(config, seed)``: the same as ``simulate(config, seed)``'s."""
    return make_layout(config, _streams(seed)[0])


def simulate_stream(
    config: SimConfig,
    seed: int,
    arrival_rate: float = 0.0,
    duration: float = 0.0,
    stats: dict[str, int] | None = None,
) -> Iterator[StreamDetection]:
    """Detections of vehicles that enter the road for ever, in stamp order (then sensor order).

    The paper's model with no episodes: vehicle i enters at ``t0_i = t0_{i-1} + U(t_min,
    t_max)`` (``start_increment_min/max``), or, with ``arrival_rate`` > 0 [vehicles/s], at
    exponential spacing of mean 1 / arrival_rate (a Poisson stream); its cruise speed and its
    speed along the road follow ``g`` exactly as in :func:`simulate`; the clutter knobs apply
    per passage (``miss_probability``, ``stamp_noise``, ``velocity_noise``), and each vehicle
    brings ``Poisson(false_alarm_rate)`` false alarms at each sensor, stamped uniformly within
    one mean entry spacing around its passage there (so the clutter density per vehicle is
    the episodes'). ``false_alarms_per_sensor`` counts per episode and so has no meaning
    here: it must be 0. ``n_targets`` is ignored.

    Stamps start at 0 (the first vehicle enters at t = 0) and never go down: a noisy stamp
    or a false alarm that would fall before one already emitted is emitted at that stamp.
    Vehicles are generated ``STREAM_LOOKAHEAD`` ahead of what is emitted; a vehicle that would
    still enter before a stamp already emitted (negative spacings) is entered at that stamp
    instead and counted in ``stats['entries_delayed']``. ``duration`` > 0 [s]: stop before the
    first stamp past it; 0: never stop. ``stats`` (optional) is filled with counters as it
    runs.
    """
    if config.false_alarms_per_sensor != 0:
        raise ValueError('false_alarms_per_sensor counts per episode; a stream needs 0')
    if not (math.isfinite(arrival_rate) and arrival_rate >= 0):
        raise ValueError('arrival_rate must be finite and >= 0')
    if not (math.isfinite(duration) and duration >= 0):
        raise ValueError('duration must be finite and >= 0')
    layout = stream_layout(config, seed)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 2**31]))
    counts = stats if stats is not None else {}
    for name in ('vehicles', 'detections', 'false_alarms', 'entries_delayed'):
        counts.setdefault(name, 0)
    if arrival_rate > 0:
        spacing = 1.0 / arrival_rate
    else:
        spacing = 0.5 * (config.start_increment_min + config.start_increment_max)
    spacing = max(spacing, 1e-9)
    step = float(config.variation_step)
    n_cells = int(math.ceil(config.road_length / step)) + 1
    cell = np.minimum((layout.positions // step).astype(np.int64), n_cells - 1)
    offset = layout.positions - cell * step
    n_sensors = layout.n_sensors
    heap: list[tuple[float, int, int, float, int, float]] = []
    entries: list[float] = []  # entry times of the generated vehicles not yet passed
    last_entry = 0.0
    emitted = 0.0  # every stamp below this was emitted [s]
    vehicle = 0
    seq = 0
    chunk = STREAM_LOOKAHEAD
    while True:
        # One chunk of vehicles: cruise speeds, spacings, speed profiles, passages.
        v0 = np.maximum(
            rng.normal(config.velocity_mean, config.velocity_std, chunk), config.min_speed
        )
        if arrival_rate > 0:
            inc = rng.exponential(spacing, chunk)
        else:
            inc = rng.uniform(config.start_increment_min, config.start_increment_max, chunk)
        speed = _speed_profiles(config, v0, rng, n_cells)
        edge = np.concatenate(
            [np.zeros((chunk, 1)), np.cumsum(step / speed[:, :-1], axis=1)], axis=1
        )
        v_at = speed[:, cell]
        rel = edge[:, cell] + offset[None, :] / v_at
        misses = rng.random((chunk, n_sensors)) < config.miss_probability
        n_fa = rng.poisson(config.false_alarm_rate, (chunk, n_sensors))
        t_noise = rng.normal(0.0, config.stamp_noise, (chunk, n_sensors))
        v_noise = rng.normal(0.0, config.velocity_noise, (chunk, n_sensors))
        for i in range(chunk):
            t0 = 0.0 if vehicle == 0 else last_entry + float(inc[i])
            if t0 < emitted:
                counts['entries_delayed'] += 1
                t0 = emitted
            last_entry = t0
            entries.append(t0)
            counts['vehicles'] += 1
            for s in range(n_sensors):
                true_t = t0 + float(rel[i, s])
                true_v = float(v_at[i, s])
                if not misses[i, s]:
                    stamp = true_t + float(t_noise[i, s])
                    velocity = max(true_v + float(v_noise[i, s]), config.min_speed)
                    heapq.heappush(heap, (stamp, s, seq, velocity, vehicle, true_v))
                    seq += 1
                for _ in range(int(n_fa[i, s])):
                    fa_t = true_t + spacing * (rng.random() - 0.5)
                    fa_v = max(
                        float(rng.normal(config.velocity_mean, config.velocity_std)),
                        config.min_speed,
                    )
                    heapq.heappush(heap, (fa_t, s, seq, fa_v, FALSE_ALARM, fa_v))
                    seq += 1
            vehicle += 1
        # Emit what no vehicle generated later can precede: stamps before the earliest entry
        # among the last STREAM_LOOKAHEAD vehicles (later ones enter after it, see above).
        horizon = min(entries[-STREAM_LOOKAHEAD:])
        del entries[:-STREAM_LOOKAHEAD]
        while heap and heap[0][0] < horizon:
            stamp, s, _, velocity, target, true_v = heapq.heappop(heap)
            stamp = max(stamp, emitted)
            if duration > 0 and stamp > duration:
                return
            emitted = stamp
            counts['detections'] += 1
            if target == FALSE_ALARM:
                counts['false_alarms'] += 1
            yield StreamDetection(s, stamp, velocity, target, true_v)
