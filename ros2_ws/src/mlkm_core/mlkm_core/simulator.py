"""Road-traffic simulator following the paper's Algorithm 1 ("Data generation").

Paper quantities and how they map here
--------------------------------------
* A 1-D road of length ``D`` (``road_length``) with ``N_S`` sensors at unique random positions
  in (0, D) (uniform, seeded, sorted along the road).
* ``N_A`` targets. Target ``i`` enters the road (x = 0) at ``t0_i = t0_{i-1} + U(t_min, t_max)``
  with ``t0_0 = 0``; the paper's U(-10, 30) lets increments be negative, so targets do not
  enter in index order.
* Initial speed ``v0_i ~ N(mu, sigma^2)``. Table I writes N(50, 40); we read the second
  argument as the *variance* (the usual N(mu, sigma^2) notation that Algorithm 1 uses), so
  ``velocity_std = sqrt(40) = 6.32 m/s``.
* ``g``, the velocity profile, is not specified by the paper. Our choice (below) is a
  mean-reverting random speed along the road.
* ``h`` records, for every sensor, the passage time and the instantaneous speed there.

The velocity-variation model ``g``
----------------------------------
Each target's speed is an Ornstein-Uhlenbeck process *in distance* ``x`` along the road,
reverting to the target's own cruise speed ``v0_i`` (drivers keep a preferred speed but
fluctuate around it)::

    dv = -(v - v0_i) dx / L + velocity_variation * sqrt(2 / L) dW(x),   v(0) = v0_i

``velocity_variation`` [m/s] is the stationary standard deviation of the fluctuation (the
strength knob; 0 gives constant speed and no overtaking from fluctuations, only from speed
differences) and ``variation_length`` L [m] is its correlation length. The process is
sampled exactly (AR(1) with coefficient exp(-dx/L)) on a grid of ``variation_step`` metres and
the speed is held constant inside each grid cell, so the passage time at any position is an
exact integral ``t(x) = t0 + int_0^x ds / v(s)``; speeds are clipped at ``min_speed`` > 0, so
passage times are strictly increasing along the road for every target. A sensor reports the
speed of the cell it sits in. Targets overtake one another (different cruise speeds, and the
fluctuations), so every sensor sees them in a different order, as the paper requires.

Calibration of the defaults
---------------------------
The paper gives neither D nor g. The defaults (D = 500 m, fluctuation std 4 m/s, correlation
length 300 m, and the associators' segment size K = 5) come from a sweep of road length
(250 m .. 4 km), fluctuation strength (0.5 .. 9 m/s), correlation length (20 m .. 1 km) and K
(2 .. 5), first with 10 and then 100 seeded datasets per point, choosing the setting where all
of the paper's qualitative findings (P above UP, Simulation 2 below Simulation 1, K-means++(P)
< MLKM w/o EC < MLKM w/ EC, the DNN's trend) hold with margin and MLKM lands near the paper's
numbers:

* A target's detections spread over D / v = 10 s along the time axis, the same as the mean
  spacing of entries (U(-10, 30) s): raw (UP) clustering mixes neighbouring targets.
* The fluctuation makes the speed a sensor reads differ from the speed the target actually
  had since the first sensor, so the preprocessing's constant-speed back-projection blurs
  each target (P): better than UP, far from perfect, and worse with 50 targets than with 10.
* MLKM's segments of K = 5 sensors span ~125 m (2.5 s), Layer 2 repairs most Layer 1
  mistakes, and Layer 3 projects centroids whose speed is a 5-sensor average; hence
  K-means++(P) < MLKM w/o EC < MLKM w/ EC.
* Longer roads (>= 1 km) ruin Layer 1 without correction (MLKM w/o EC falls below P); weak
  fluctuation (< 3 m/s) puts P above MLKM w/o EC; long correlation (>= 1 km) helps every
  method.

The same default simulator also has to leave the stronger associators room to be
near-perfect (the benchmark's targets in paper and clutter mode at 50/20, ``mlkm bench``). A
second sweep (fluctuation 2 .. 5 m/s x correlation 50 m .. 1 km, the paper's relations and
``multiframe`` together) showed that a stronger fluctuation makes the traffic itself too
ambiguous for those targets, while 4 m/s keeps every one of the paper's relations and brings
the error-correction gain closest to the paper's; a much weaker one lets K-means++(P) overtake
MLKM w/o EC. The figures of both sweeps are in docs/benchmarks.md; ``mlkm paper``
(``results/paper/results.md``) checks the paper's relations on the defaults.

Clutter knobs (all off by default, so the paper's setting is unchanged)
----------------------------------------------------------------------
* ``miss_probability``: each passage is independently not reported with this probability.
* ``false_alarm_rate``: expected false alarms per sensor *per target* in an episode (the
  benchmark's "0.05 false alarms per target per sensor"); ``false_alarms_per_sensor`` adds an
  absolute expected number per sensor per episode. The count at each sensor is Poisson with
  mean ``false_alarm_rate * n_targets + false_alarms_per_sensor``. A false alarm's stamp is
  uniform over the interval in which that sensor sees true traffic, its speed is drawn from the
  cruise-speed distribution; its ``target`` is ``FALSE_ALARM`` (-1).
* ``stamp_noise`` [s] and ``velocity_noise`` [m/s]: zero-mean Gaussian measurement noise added
  to every reported stamp and speed (true passages and false alarms alike). Reported speeds are
  clipped at ``min_speed``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from mlkm_core.types import FALSE_ALARM, Dataset, Detections, Layout


@dataclass(frozen=True)
class SimConfig:
    """Scenario of one episode. Units: metres, seconds, metres per second."""

    road_length: float = 500.0  # D [m]
    n_sensors: int = 20  # N_S
    n_targets: int = 50  # N_A
    velocity_mean: float = 50.0  # mu of the cruise speed [m/s]
    velocity_std: float = math.sqrt(40.0)  # sigma [m/s]; the paper's N(50, 40) is a variance
    start_increment_min: float = -10.0  # t_min of t0_i - t0_{i-1} ~ U(t_min, t_max) [s]
    start_increment_max: float = 30.0  # t_max [s]
    velocity_variation: float = 4.0  # stationary std of the speed fluctuation of g [m/s]
    variation_length: float = 300.0  # correlation length L of the fluctuation [m]
    variation_step: float = 5.0  # grid on which g is sampled [m]
    min_speed: float = 1.0  # speeds are clipped at this floor [m/s]
    miss_probability: float = 0.0  # per passage, in [0, 1)
    false_alarm_rate: float = 0.0  # expected false alarms per sensor per target
    false_alarms_per_sensor: float = 0.0  # expected false alarms per sensor (absolute)
    stamp_noise: float = 0.0  # std of Gaussian stamp noise [s]
    velocity_noise: float = 0.0  # std of Gaussian speed noise [m/s]

    def __post_init__(self) -> None:
        checks = [
            (self.road_length > 0, 'road_length must be > 0'),
            (self.n_sensors >= 1, 'n_sensors must be >= 1'),
            (self.n_targets >= 1, 'n_targets must be >= 1'),
            (self.velocity_mean > 0, 'velocity_mean must be > 0'),
            (self.velocity_std >= 0, 'velocity_std must be >= 0'),
            (
                self.start_increment_min <= self.start_increment_max,
                'start_increment_min must be <= start_increment_max',
            ),
            (self.velocity_variation >= 0, 'velocity_variation must be >= 0'),
            (self.variation_length > 0, 'variation_length must be > 0'),
            (self.variation_step > 0, 'variation_step must be > 0'),
            (self.min_speed > 0, 'min_speed must be > 0'),
            (0 <= self.miss_probability < 1, 'miss_probability must be in [0, 1)'),
            (self.false_alarm_rate >= 0, 'false_alarm_rate must be >= 0'),
            (self.false_alarms_per_sensor >= 0, 'false_alarms_per_sensor must be >= 0'),
            (self.stamp_noise >= 0, 'stamp_noise must be >= 0'),
            (self.velocity_noise >= 0, 'velocity_noise must be >= 0'),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(message)


def make_layout(config: SimConfig, seed: int | np.random.Generator) -> Layout:
    """Unique uniform random sensor positions in (0, D), sorted; ids 0..N_S-1."""
    rng = seed if isinstance(seed, np.random.Generator) else _streams(seed)[0]
    d = float(config.road_length)
    while True:
        pos = np.sort(rng.uniform(0.0, d, config.n_sensors))
        if pos[0] > 0 and pos[-1] < d and np.all(np.diff(pos) > 0):
            return Layout(d, pos)


def _streams(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    layout_seq, traffic_seq = np.random.SeedSequence(int(seed)).spawn(2)
    return np.random.default_rng(layout_seq), np.random.default_rng(traffic_seq)


def _speed_profiles(
    config: SimConfig, v0: np.ndarray, rng: np.random.Generator, n_cells: int
) -> np.ndarray:
    """Speed of each target in each grid cell, shape (n_targets, n_cells): OU around v0."""
    a = math.exp(-config.variation_step / config.variation_length)
    noise = rng.standard_normal((v0.size, n_cells))
    noise[:, 0] = 0.0  # v(0) = v0: the fluctuation starts at zero
    # the AR(1) recursion dev[k] = b noise[k] + a dev[k-1], cell by cell over every target at
    # once (what scipy.signal.lfilter computes, to the bit, without its 1.5 s import in every
    # process that simulates)
    dev = config.velocity_variation * math.sqrt(1.0 - a * a) * noise
    for k in range(1, n_cells):
        dev[:, k] += a * dev[:, k - 1]
    return np.maximum(v0[:, None] + dev, config.min_speed)


def _passages(
    config: SimConfig, layout: Layout, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """True passage times and speeds, shape (n_targets, n_sensors)."""
    n = config.n_targets
    v0 = rng.normal(config.velocity_mean, config.velocity_std, n)
    v0 = np.maximum(v0, config.min_speed)
    inc = rng.uniform(config.start_increment_min, config.start_increment_max, n)
    inc[0] = 0.0
    t0 = np.cumsum(inc)
    step = float(config.variation_step)
    n_cells = int(math.ceil(config.road_length / step)) + 1
    speed = _speed_profiles(config, v0, rng, n_cells)
    # time at the left edge of each cell: t0 + sum of step / v over the cells before
    edge_time = (
        np.concatenate([np.zeros((n, 1)), np.cumsum(step / speed[:, :-1], axis=1)], axis=1)
        + t0[:, None]
    )
    cell = np.minimum((layout.positions // step).astype(np.int64), n_cells - 1)
    offset = layout.positions - cell * step
    v_at = speed[:, cell]
    t_at = edge_time[:, cell] + offset[None, :] / v_at
    return t_at, v_at


def simulate(config: SimConfig, seed: int, layout: Layout | None = None) -> Dataset:
    """One seeded episode. Detections are sorted by (sensor_index, stamp).

    The layout comes from ``seed`` unless one is given (episodes of a live run share it).
    """
    layout_rng, rng = _streams(seed)
    if layout is None:
        layout = make_layout(config, layout_rng)
    elif layout.n_sensors != config.n_sensors:
        raise ValueError('layout has a different number of sensors than the config')
    return _episode(config, layout, rng)


def _episode(config: SimConfig, layout: Layout, rng: np.random.Generator) -> Dataset:
    n, s = config.n_targets, layout.n_sensors
    t_at, v_at = _passages(config, layout, rng)
    sensor = np.broadcast_to(np.arange(s), (n, s)).ravel()
    target = np.broadcast_to(np.arange(n)[:, None], (n, s)).ravel()
    stamp, velocity = t_at.ravel(), v_at.ravel()
    if config.miss_probability > 0:
        keep = rng.random(stamp.size) >= config.miss_probability
        sensor, target, stamp, velocity = sensor[keep], target[keep], stamp[keep], velocity[keep]
    fa_mean = config.false_alarm_rate * n + config.false_alarms_per_sensor
    if fa_mean > 0:
        counts = rng.poisson(fa_mean, s)
        fa_sensor = np.repeat(np.arange(s), counts)
        lo, hi = t_at.min(axis=0)[fa_sensor], t_at.max(axis=0)[fa_sensor]
        fa_stamp = lo + (hi - lo) * rng.random(fa_sensor.size)
        fa_vel = np.maximum(
            rng.normal(config.velocity_mean, config.velocity_std, fa_sensor.size), config.min_speed
        )
        sensor = np.concatenate([sensor, fa_sensor])
        target = np.concatenate([target, np.full(fa_sensor.size, FALSE_ALARM)])
        stamp = np.concatenate([stamp, fa_stamp])
        velocity = np.concatenate([velocity, fa_vel])
    if config.stamp_noise > 0:
        stamp = stamp + rng.normal(0.0, config.stamp_noise, stamp.size)
    if config.velocity_noise > 0:
        velocity = np.maximum(
            velocity + rng.normal(0.0, config.velocity_noise, velocity.size), config.min_speed
        )
    order = np.lexsort((stamp, sensor))
    dets = Detections(sensor[order], stamp[order], velocity[order], target[order])
    return Dataset(layout, dets, n)


def time_window(dataset: Dataset) -> tuple[float, float]:
    """(first, last) detection stamp of an episode [s]; (0, 0) when it has no detections."""
    stamps = dataset.detections.stamp
    if stamps.size == 0:
        return 0.0, 0.0
    return float(stamps.min()), float(stamps.max())


def stream_origin(datasets: list[Dataset]) -> float:
    """Whole seconds to add to every stamp so that no episode starts before t = 0.

    Start times may be negative (a negative start-time increment moves the first targets
    before t = 0), but a live stream carries ROS times, which cannot be. Adding the same whole
    number of seconds to every stamp keeps all relative times, hence every result, unchanged.
    """
    first = min((time_window(d)[0] for d in datasets), default=0.0)
    return float(math.ceil(-first)) if first < 0 else 0.0


def shift(dataset: Dataset, offset: float) -> Dataset:
    """The same episode with every stamp moved by ``offset`` seconds."""
    d = dataset.detections
    return Dataset(
        dataset.layout,
        Detections(d.sensor_index, d.stamp + offset, d.velocity, d.target),
        dataset.n_targets,
    )


def simulate_episodes(
    config: SimConfig, seed: int, n_episodes: int, gap: float = 10.0
) -> list[Dataset]:
    """Back-to-back episodes on one shared layout, with non-overlapping time windows.

    Episode 0 is ``simulate(config, seed)`` unchanged; episode k >= 1 has its own traffic and
    is shifted so that it starts ``gap`` seconds after episode k-1 ends (see ``time_window``).
    """
    return list(iter_episodes(config, seed, n_episodes, gap))


def iter_episodes(
    config: SimConfig, seed: int, n_episodes: int, gap: float = 10.0
) -> Iterator[Dataset]:
    """The episodes of ``simulate_episodes`` one at a time (a long run in constant memory)."""
    if n_episodes < 0:
        raise ValueError('n_episodes must be >= 0')
    if gap < 0:
        raise ValueError('gap must be >= 0')
    if n_episodes == 0:
        return
    prev = simulate(config, seed)
    yield prev
    layout = prev.layout
    for k in range(1, n_episodes):
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), k]))
        ep = _episode(config, layout, rng)
        start = time_window(ep)[0]
        prev = shift(ep, time_window(prev)[1] + gap - start)
        yield prev
