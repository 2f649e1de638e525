"""Datasets from SUMO: a batch (``generate``), episodes, and a time-ordered passage stream.

All three drive the same step-wise ``SumoRun`` and the same measurement model. Ground truth
is the SUMO vehicle: targets are numbered 0, 1, ... in the order vehicles are first detected
(``SumoDataset.vehicle_ids[target]`` is the SUMO id); double reports and false alarms have
target -1.
"""

from __future__ import annotations

import heapq
import math
import time as _time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from mlkm_core.types import FALSE_ALARM, Dataset, Detections

from .measurement import PASSAGE, MeasurementConfig, MeasurementStats, Passages, apply
from .network import ScenarioFiles, SumoError
from .runner import SumoRun
from .scenarios import Road, make_road, scenario

#: Safety limit: a run with ``n_vehicles`` stops this long [s] after the last departure even
#: if vehicles are still in the network (they are then counted in ``stats['in_network']``).
DRAIN_LIMIT = 1800.0


@dataclass
class SumoDataset(Dataset):
    """A ``Dataset`` with what SUMO adds: the road (lanes per station, ramps), the SUMO id
    of every target, the kind of every detection (``measurement.KIND_NAMES``) and counts;
    per detection also the SUMO id of the vehicle behind it ('' for a false alarm; a double
    report has its vehicle's id but target -1) and its speed before measurement noise."""

    road: Road | None = None
    vehicle_ids: tuple[str, ...] = ()
    kind: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    stats: dict = field(default_factory=dict)
    vehicle: np.ndarray = field(default_factory=lambda: np.zeros(0, object))
    true_speed: np.ndarray = field(default_factory=lambda: np.zeros(0))


def _rngs(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    layout_seq, measure_seq = np.random.SeedSequence(seed).spawn(2)
    return np.random.default_rng(layout_seq), np.random.default_rng(measure_seq)


def road(
    scenario_name: str,
    n_stations: int = 20,
    seed: int = 1,
    stations_at: list[float] | np.ndarray | None = None,
    cache_dir: str | Path | None = None,
) -> Road:
    """The road (network and stations) that ``generate``, ``episodes`` and ``PassageStream``
    use for the same arguments and seed, without running SUMO. Raises SumoError."""
    scenario(scenario_name)
    return make_road(scenario_name, n_stations, _rngs(seed)[0], stations_at, cache_dir)


def to_dataset(road: Road, measured: Passages, stats: dict) -> SumoDataset:
    """Detections (sorted by time) with truth, lane and length from measured passages."""
    measured = measured.sorted()
    target = np.full(len(measured), FALSE_ALARM, np.int64)
    ids: dict[str, int] = {}
    for k in np.flatnonzero(measured.kind == PASSAGE):
        target[k] = ids.setdefault(measured.vehicle[k], len(ids))
    dets = Detections(
        measured.station, measured.time, measured.speed, target, measured.lane, measured.length
    )
    return SumoDataset(
        road.layout,
        dets,
        len(ids),
        road,
        tuple(ids),
        measured.kind.copy(),
        dict(stats),
        measured.vehicle.copy(),
        measured.true_speed.copy(),
    )


def _stats(run: SumoRun, mstats: MeasurementStats, wall: float, start: float) -> dict:
    return {
        'scenario': run.road.scenario,
        'simulated_s': run.time - start,
        'wall_s': wall,
        'vehicles_inserted': run.inserted,
        'vehicles_arrived': run.arrived,
        'teleports': run.teleports,
        'in_network': run.pending,
        **vars(mstats),
    }


def _progress(enabled: bool, total: float, unit: str):
    from tqdm import tqdm

    return tqdm(total=total, unit=unit, disable=not enabled, leave=False, dynamic_ncols=True)


def _run_until(run: SumoRun, limit: float, bar, drain: bool) -> Passages:
    """Step until time ``limit`` [s] or, with ``drain``, until no vehicle is left."""
    parts = []
    last_arrived = run.arrived
    while run.time < limit and not (drain and run.pending == 0):
        parts.append(run.step())
        if drain:
            bar.update(run.arrived - last_arrived)
            last_arrived = run.arrived
        else:
            bar.update(run.step_length)
    return Passages.concatenate(parts)


def generate(
    scenario_name: str,
    n_vehicles: int | None = None,
    n_stations: int = 20,
    seed: int = 1,
    duration: float | None = None,
    stations_at: list[float] | np.ndarray | None = None,
    measurement: MeasurementConfig | None = None,
    progress: bool = False,
    cache_dir: str | Path | None = None,
    step_length: float = 0.2,
    flow: float | None = None,
    files: ScenarioFiles | None = None,
) -> SumoDataset:
    """Run SUMO headless and return the detections of ``n_vehicles`` vehicles (all of them
    driven until they left the road, at most ``duration`` s if given) or, without
    ``n_vehicles``, of ``duration`` seconds of continuous traffic.

    ``flow`` [veh/h] overrides the scenario's demand. ``files`` replaces the named scenario's
    sources (a road of ``families``, which then needs ``flow``; ``scenario_name`` is a label).
    Raises SumoError (bad scenario, layout, netconvert or SUMO failure) and ValueError (bad
    measurement parameters)."""
    if files is not None and not flow:
        raise SumoError('a road from its own sources needs a flow')
    sc = scenario(scenario_name) if files is None else None
    if n_vehicles is None and duration is None:
        raise SumoError('give n_vehicles, duration, or both')
    if n_vehicles is not None and n_vehicles < 1:
        raise SumoError(f'n_vehicles must be >= 1, got {n_vehicles}')
    if duration is not None and not duration > 0:
        raise SumoError(f'duration must be > 0 s, got {duration}')
    measurement = measurement or MeasurementConfig()
    layout_rng, measure_rng = _rngs(seed)
    road = make_road(scenario_name, n_stations, layout_rng, stations_at, cache_dir, files)
    flow = flow or sc.flow
    wall0 = _time.perf_counter()
    with SumoRun(road, seed, step_length) as run:
        if n_vehicles is not None:
            run.add_demand(flow, n_vehicles=n_vehicles)
            limit = run.last_departure + DRAIN_LIMIT
            if duration is not None:
                limit = min(limit, duration)
            with _progress(progress, n_vehicles, 'veh') as bar:
                truth = _run_until(run, limit, bar, drain=True)
        else:
            run.add_demand(flow, until=duration)
            with _progress(progress, duration, 's') as bar:
                truth = _run_until(run, duration, bar, drain=False)
        mstats = MeasurementStats()
        measured = apply(measurement, truth, road.lanes, 0.0, run.time, measure_rng, mstats)
        stats = _stats(run, mstats, _time.perf_counter() - wall0, 0.0)
    return to_dataset(road, measured, stats)


def episodes(
    scenario_name: str,
    n_vehicles: int,
    n_episodes: int | None = None,
    n_stations: int = 20,
    seed: int = 1,
    stations_at: list[float] | np.ndarray | None = None,
    measurement: MeasurementConfig | None = None,
    cache_dir: str | Path | None = None,
    step_length: float = 0.2,
    flow: float | None = None,
) -> Iterator[SumoDataset]:
    """Episodes on one road and one SUMO run: each releases a batch of ``n_vehicles`` at the
    scenario's flow and ends when all of them left the road; ``n_episodes=None`` runs on.
    Stamps continue across episodes (SUMO time); targets restart at 0 in every episode."""
    sc = scenario(scenario_name)
    if n_vehicles < 1:
        raise SumoError(f'n_vehicles must be >= 1, got {n_vehicles}')
    measurement = measurement or MeasurementConfig()
    layout_rng, measure_rng = _rngs(seed)
    road = make_road(scenario_name, n_stations, layout_rng, stations_at, cache_dir)
    with SumoRun(road, seed, step_length) as run:
        k = 0
        while n_episodes is None or k < n_episodes:
            wall0, start = _time.perf_counter(), run.time
            inserted0, arrived0 = run.inserted, run.arrived
            run.add_demand(flow or sc.flow, n_vehicles=n_vehicles)
            limit = run.last_departure + DRAIN_LIMIT
            with _progress(False, n_vehicles, 'veh') as bar:
                truth = _run_until(run, limit, bar, drain=True)
            mstats = MeasurementStats()
            measured = apply(measurement, truth, road.lanes, start, run.time, measure_rng, mstats)
            stats = _stats(run, mstats, _time.perf_counter() - wall0, start)
            stats['vehicles_inserted'] = run.inserted - inserted0
            stats['vehicles_arrived'] = run.arrived - arrived0
            stats['episode'] = k
            yield to_dataset(road, measured, stats)
            k += 1


class Passage(NamedTuple):
    """One measured loop report of the stream."""

    time: float  # [s]
    station: int  # index into road.layout
    position: float  # [m]
    lane: int  # index from the right
    speed: float  # [m/s]
    length: float  # [m]
    vehicle: str  # SUMO id, '' for a false alarm
    kind: int  # measurement.PASSAGE / DOUBLE_REPORT / FALSE_ALARM
    true_speed: float = math.nan  # before measurement noise [m/s]


class PassageStream:
    """Measured passages in time order while SUMO runs (for a continuous live source).

    ``road`` is known before iterating; iterating starts SUMO and yields ``Passage``s until
    ``duration`` [s] (or forever without it), with continuous demand at the scenario's flow.
    Each simulation step is measured on its own; with stamp jitter the stream holds reports
    back by six jitter standard deviations so that they still come out in time order. On a
    road network (``road_networks.network_stream``) a passage's station is the network's
    station index and its position is along the station's link."""

    def __init__(
        self,
        scenario_name: str,
        n_stations: int = 20,
        seed: int = 1,
        duration: float | None = None,
        stations_at: list[float] | np.ndarray | None = None,
        measurement: MeasurementConfig | None = None,
        cache_dir: str | Path | None = None,
        step_length: float = 0.2,
        flow: float | None = None,
    ) -> None:
        self.scenario = scenario(scenario_name)
        layout_rng, rng = _rngs(seed)
        built = make_road(scenario_name, n_stations, layout_rng, stations_at, cache_dir)
        self._setup(built, built.layout.positions, seed, flow or self.scenario.flow, rng,
                    duration, measurement, step_length)  # fmt: skip

    @classmethod
    def on_road(
        cls,
        built,
        positions: np.ndarray,
        seed: int,
        flow: float,
        rng: np.random.Generator,
        duration: float | None = None,
        measurement: MeasurementConfig | None = None,
        step_length: float = 0.2,
    ) -> PassageStream:
        """The stream on a road already built (``built``: what ``SumoRun`` drives, with its
        route distribution ``demand``; ``positions`` [m] of its stations), at ``flow``
        [veh/h], measured with ``rng``."""
        self = cls.__new__(cls)
        self.scenario = None
        self._setup(built, positions, seed, flow, rng, duration, measurement, step_length)
        return self

    def _setup(self, built, positions, seed, flow, rng, duration, measurement, step_length):
        self.road = built
        self.positions = np.asarray(positions, float)
        self.seed = seed
        self.flow = flow
        self._rng = rng
        self.duration = duration
        self.measurement = measurement or MeasurementConfig()
        self.step_length = step_length
        self.stats = MeasurementStats()

    def __iter__(self) -> Iterator[Passage]:
        pos = self.positions
        hold = 6.0 * self.measurement.stamp_jitter
        heap: list[tuple] = []
        with SumoRun(self.road, self.seed, self.step_length) as run:
            demand_until = 0.0  # departures are scheduled up to here [s]
            while self.duration is None or run.time < self.duration:
                if run.time + 120.0 >= demand_until and (
                    self.duration is None or demand_until < self.duration
                ):
                    new = demand_until + 600.0
                    if self.duration is not None:
                        new = min(new, self.duration)
                    run.add_demand(self.flow, until=new, start=demand_until)
                    demand_until = new
                t0 = run.time
                step = apply(
                    self.measurement, run.step(), self.road.lanes, t0, run.time, self._rng,
                    self.stats,
                )  # fmt: skip
                for k in range(len(step)):
                    st = int(step.station[k])
                    p = Passage(
                        float(step.time[k]), st, float(pos[st]), int(step.lane[k]),
                        float(step.speed[k]), float(step.length[k]), str(step.vehicle[k]),
                        int(step.kind[k]), float(step.true_speed[k]),
                    )  # fmt: skip
                    heapq.heappush(heap, p)
                while heap and heap[0].time <= run.time - hold:
                    yield heapq.heappop(heap)
            while heap:
                yield heapq.heappop(heap)
