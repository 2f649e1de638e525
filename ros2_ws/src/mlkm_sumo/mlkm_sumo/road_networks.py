"""Road-network datasets from SUMO: an interchange, a signalised arterial and a small grid.

``draw_network(family, seed, **overrides)`` draws a scenario from its family's ranges
(``network_families``); ``generate_network(draw)`` builds it (``network_sources``: plain-XML
sources, the netconvert cache, retimed signals) and simulates it with the same step-wise
``runner.SumoRun`` and measurement model as the single roads: ``draw.vehicles`` vehicles at
``draw.flow`` vehicles/h, each on a route drawn by SUMO from the draw's route distribution,
loop stations (one loop per lane) on the links, run until every vehicle has left.
``write_network_dataset`` writes the detections CSV and the network layout file of the
contract.

Station ids are 0, 1, ... in the order of ``mapping['stations']`` (so an id is also the index
of its station); link ids likewise index ``mapping['links']``. Ground truth as in
``api``: targets numbered in the order vehicles are first detected, double reports and false
alarms target -1; ``routes[target]`` is the list of link ids the vehicle drove.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from mlkm_core.csvout import write_detections
from mlkm_core.types import FALSE_ALARM, Detections

from .api import DRAIN_LIMIT, PassageStream
from .measurement import (
    CSV_DECIMALS,
    PASSAGE,
    MeasurementConfig,
    MeasurementStats,
    Passages,
    apply,
)
from .network_families import NETWORK_FAMILIES, NetworkDraw, draw_network
from .network_sources import NetworkRoad, build_draw
from .runner import SumoRun

__all__ = [
    'NETWORK_FAMILIES',
    'NetworkDataset',
    'NetworkDraw',
    'draw_network',
    'generate_network',
    'write_network_dataset',
]

#: SUMO step length [s] of a network run.
STEP_LENGTH = 0.2
#: First line of a written layout file.
LAYOUT_HEADER = '# a road network from SUMO (mlkm_sumo.road_networks): {family}, seed {seed}\n'


def _col(dtype) -> np.ndarray:
    return field(default_factory=lambda: np.zeros(0, dtype))


@dataclass
class NetworkDataset:
    """Detections of one network run as parallel arrays, sorted by stamp, with the layout
    (``mapping``, the contract's mapping form) and the truth (module docstring)."""

    draw: NetworkDraw
    mapping: dict
    station: np.ndarray = _col(np.int64)  # station id
    stamp: np.ndarray = _col(float)  # [s]
    speed: np.ndarray = _col(float)  # [m/s]
    lane: np.ndarray = _col(np.int64)  # index from the right
    length: np.ndarray = _col(float)  # vehicle length [m]
    target: np.ndarray = _col(np.int64)  # true vehicle, -1 = double report or false alarm
    kind: np.ndarray = _col(np.int64)  # measurement.PASSAGE / DOUBLE_REPORT / FALSE_ALARM
    vehicle: np.ndarray = _col(object)  # SUMO id ('' for a false alarm)
    true_speed: np.ndarray = _col(float)  # before measurement noise [m/s]
    vehicle_ids: tuple[str, ...] = ()  # SUMO id per target
    routes: tuple[tuple[int, ...], ...] = ()  # link ids driven, per target
    stats: dict = field(default_factory=dict)
    #: (from link, to link) -> length [m] of the way through their junction, which no
    #: link's length holds (``network_sources.junction_lengths``)
    junction_lengths: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.stamp.size)

    @property
    def n_targets(self) -> int:
        return len(self.vehicle_ids)

    @property
    def station_links(self) -> np.ndarray:
        """Link id per station."""
        return np.array([s['link'] for s in self.mapping['stations']], np.int64)

    @property
    def station_positions(self) -> np.ndarray:
        """Position along its link per station [m]."""
        return np.array([s['position_m'] for s in self.mapping['stations']], float)

    def detections(self) -> Detections:
        """The core's ``Detections``; ``sensor_index`` is the station id."""
        return Detections(
            self.station, self.stamp, self.speed, self.target, self.lane, self.length
        )


class _RouteRun(SumoRun):
    """A SumoRun that also records the route (SUMO edges) of every vehicle that departs."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.vehicle_routes: dict[str, tuple[str, ...]] = {}

    def step(self) -> Passages:
        import libsumo

        out = super().step()
        for vid in libsumo.simulation.getDepartedIDList():
            self.vehicle_routes[vid] = tuple(libsumo.vehicle.getRoute(vid))
        return out


def _to_dataset(
    d: NetworkDraw, road: NetworkRoad, measured: Passages, routes: dict, stats: dict
) -> NetworkDataset:
    measured = measured.sorted()
    target = np.full(len(measured), FALSE_ALARM, np.int64)
    ids: dict[str, int] = {}
    for k in np.flatnonzero(measured.kind == PASSAGE):
        target[k] = ids.setdefault(measured.vehicle[k], len(ids))
    link_of = {e: k for k, e in enumerate(road.edge_ids)}
    truth = tuple(tuple(link_of[e] for e in routes.get(v, ())) for v in ids)
    return NetworkDataset(
        d, road.mapping, measured.station, measured.time, measured.speed, measured.lane,
        measured.length, target, measured.kind, measured.vehicle, measured.true_speed,
        tuple(ids), truth, stats, dict(road.junction_lengths),
    )  # fmt: skip


def generate_network(
    draw: NetworkDraw,
    cache_dir: str | Path | None = None,
    measurement: MeasurementConfig | None = None,
    step_length: float = STEP_LENGTH,
) -> NetworkDataset:
    """Build and simulate ``draw`` (module docstring); SUMO and the measurement model are
    seeded with ``draw.seed``. Raises SumoError."""
    measurement = measurement or MeasurementConfig()
    road = build_draw(draw, cache_dir)
    measure_rng = _measure_rng(draw)
    wall0 = _time.perf_counter()
    with _RouteRun(road, draw.seed, step_length) as run:
        run.add_demand(draw.flow, n_vehicles=draw.vehicles)
        limit = run.last_departure + DRAIN_LIMIT
        parts = []
        while run.time < limit and run.pending > 0:
            parts.append(run.step())
        truth = Passages.concatenate(parts)
        mstats = MeasurementStats()
        measured = apply(measurement, truth, road.lanes, 0.0, run.time, measure_rng, mstats)
        stats = {
            'family': draw.family,
            'seed': draw.seed,
            'simulated_s': run.time,
            'wall_s': _time.perf_counter() - wall0,
            'vehicles_inserted': run.inserted,
            'vehicles_arrived': run.arrived,
            'teleports': run.teleports,
            'in_network': run.pending,
            **vars(mstats),
        }
        routes = dict(run.vehicle_routes)
    return _to_dataset(draw, road, measured, routes, stats)


def _measure_rng(draw: NetworkDraw) -> np.random.Generator:
    """The measurement model's generator of a draw's run."""
    return np.random.default_rng([int(draw.seed), 0x4E7])


def network_stream(
    draw: NetworkDraw,
    duration: float | None = None,
    measurement: MeasurementConfig | None = None,
    cache_dir: str | Path | None = None,
    step_length: float = STEP_LENGTH,
    road: NetworkRoad | None = None,
) -> PassageStream:
    """Continuous traffic on the network of ``draw``: departures at its flow, on its routes
    with their shares, until ``duration`` [s] or forever (None), measured as passages come
    (``PassageStream``); a passage's station is the network's station index and its
    position is along that station's link. SUMO, the departures and the measurement are
    seeded with ``draw.seed``. ``road``: the draw already built (``build_draw``). Raises
    SumoError."""
    road = road or build_draw(draw, cache_dir)
    return PassageStream.on_road(
        road, np.array(road.loop_pos), draw.seed, draw.flow, _measure_rng(draw), duration,
        measurement, step_length,
    )  # fmt: skip


@dataclass(frozen=True)
class _StationTable:
    """What ``csvout.write_detections`` reads of a layout: the id and the position of each
    station (on a network, along its own link: not increasing, so not a ``Layout``)."""

    sensor_ids: np.ndarray
    positions: np.ndarray


def write_network_dataset(
    ds: NetworkDataset, csv_path: str | Path, layout_path: str | Path
) -> None:
    """The detections CSV (the product's columns, ``position_m`` along the station's link)
    and the network layout file (YAML, the contract's network form)."""
    table = _StationTable(
        np.array([s['id'] for s in ds.mapping['stations']], np.int64), ds.station_positions
    )
    write_detections(csv_path, table, ds.detections(), decimals=CSV_DECIMALS)
    layout_path = Path(layout_path)
    layout_path.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(ds.mapping, sort_keys=False, default_flow_style=None, width=200)
    layout_path.write_text(LAYOUT_HEADER.format(family=ds.draw.family, seed=ds.draw.seed) + text)
