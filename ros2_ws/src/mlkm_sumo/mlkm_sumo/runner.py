"""One SUMO simulation, advanced step by step in this process (libsumo).

``SumoRun.step()`` advances one simulation step and returns the loop passages of that step,
sorted by time: every passage of a later step is later, so concatenating the steps gives the
passages in time order (the batch, episode and streaming modes all consume this).

The loops are SUMO ``inductionLoop``s whose vehicle data is read after each step. SUMO's
``instantInductionLoop`` reports the same passages (including the second report of a vehicle
that changes lane on top of a loop) but only into a file that SUMO flushes in 8 kB blocks,
which a time-ordered stream cannot wait for; ``instant_output`` adds those loops for an
audit. A loop's entry time is interpolated within the step; speed and length are the
vehicle's at the end of that step (as the instant loop reports them).

The demand inserts vehicles ``v<k>`` (k = 0, 1, ...) at the upstream end (and on-ramps)
as a Poisson process at the scenario's flow, each with a route drawn by SUMO from the
scenario's routeDistribution ``demand`` and a type from the vTypeDistribution ``mix``.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from .measurement import DOUBLE_REPORT, MIN_SPEED, PASSAGE, Passages
from .network import SumoError, binary, scenario_files, sumo_env
from .scenarios import Road, loop_id, write_detectors

#: Vehicles are handed to SUMO this far [s] ahead of their departure.
_DEMAND_AHEAD = 60.0
_active = False  # libsumo runs one simulation per process


class SumoRun:
    """A started SUMO simulation of ``road``; use as a context manager."""

    def __init__(
        self,
        road: Road,
        seed: int = 1,
        step_length: float = 0.2,
        instant_output: str | Path | None = None,
    ) -> None:
        if not 0 < step_length <= 1.0:
            raise SumoError(f'step_length must lie in (0, 1] s, got {step_length}')
        self.road = road
        self.seed = int(seed)
        self.step_length = float(step_length)
        self.instant_output = Path(instant_output) if instant_output else None
        self.time = 0.0
        self.inserted = 0  # vehicles handed to SUMO
        self.arrived = 0
        self.teleports = 0
        self._rng = np.random.default_rng([self.seed, 0x5A0])
        self._schedule: list[float] = []  # future departure times not yet handed to SUMO
        self.last_departure = 0.0  # latest scheduled departure [s]
        self._next_id = 0
        self._reported: dict[str, set[tuple[str, float]]] = {}  # vehicle -> (loop, entry)
        self._seen: dict[str, set[int]] = {}  # vehicle -> stations that reported it
        self._loops: dict[str, tuple[int, int]] = {}
        self._tmp: tempfile.TemporaryDirectory | None = None
        self._started = False

    # --- life cycle ---------------------------------------------------------------------------
    def __enter__(self) -> SumoRun:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self) -> None:
        global _active
        if _active:
            raise SumoError('another SUMO run is active in this process (libsumo runs one)')
        import libsumo

        files = self.road.files or scenario_files(self.road.scenario)
        self._tmp = tempfile.TemporaryDirectory(prefix='mlkm_sumo_')
        det = Path(self._tmp.name) / 'detectors.add.xml'
        write_detectors(self.road, det, self.instant_output)
        cmd = [
            str(binary('sumo')),
            '--net-file', str(self.road.net_file),
            '--additional-files', ','.join(map(str, (files.vtypes, files.routes, det))),
            '--step-length', f'{self.step_length:g}',
            '--seed', str(self.seed),
            '--begin', '0',
            '--no-step-log', 'true',
            '--no-warnings', 'true',
            '--duration-log.disable', 'true',
        ]  # fmt: skip
        os.environ.setdefault('SUMO_HOME', sumo_env()['SUMO_HOME'])
        try:
            libsumo.start(cmd)
        except Exception as exc:  # libsumo raises TraCIException / FatalTraCIError
            self._tmp.cleanup()
            raise SumoError(
                f'SUMO failed to start scenario {self.road.scenario!r}: {exc}'
            ) from None
        _active = True
        self._started = True
        for i, lanes in enumerate(self.road.loops):
            for lane in range(len(lanes)):
                lid = loop_id(i, lane)
                self._loops[lid] = (i, lane)

    def close(self) -> None:
        global _active
        if self._started:
            import libsumo

            try:
                libsumo.close()
            finally:
                self._started = False
                _active = False
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    # --- demand -------------------------------------------------------------------------------
    def add_demand(
        self,
        flow: float,
        n_vehicles: int | None = None,
        until: float | None = None,
        start: float | None = None,
    ) -> None:
        """Schedule departures at ``flow`` [veh/h] as a Poisson process from ``start`` (default:
        now, or the last scheduled departure if later): ``n_vehicles`` of them, or all before
        time ``until`` [s]."""
        if not flow > 0:
            raise SumoError(f'flow must be > 0 vehicles/h, got {flow}')
        if n_vehicles is None and until is None:
            raise SumoError('add_demand needs n_vehicles or until')
        t = max(self.time, self.last_departure) if start is None else start
        mean_gap = 3600.0 / flow
        added = 0
        while n_vehicles is None or added < n_vehicles:
            t += float(self._rng.exponential(mean_gap))
            if until is not None and t >= until:
                break
            self._schedule.append(t)
            self.last_departure = t
            added += 1

    def _hand_over(self) -> None:
        import libsumo

        while self._schedule and self._schedule[0] <= self.time + _DEMAND_AHEAD:
            depart = max(self._schedule.pop(0), self.time + self.step_length)
            vid = f'v{self._next_id}'
            self._next_id += 1
            libsumo.vehicle.add(
                vid,
                'demand',
                typeID='mix',
                depart=f'{depart:.3f}',
                departLane='best',
                departSpeed='max',
            )
            self.inserted += 1

    @property
    def pending(self) -> int:
        """Vehicles scheduled or in SUMO (in the network or waiting to be inserted)."""
        import libsumo

        return len(self._schedule) + libsumo.simulation.getMinExpectedNumber()

    # --- stepping -----------------------------------------------------------------------------
    def step(self) -> Passages:
        """Advance one step; the passages that happened in it, sorted by time."""
        import libsumo

        self._hand_over()
        libsumo.simulationStep()
        now = libsumo.simulation.getTime()
        self.time = now
        self.teleports += libsumo.simulation.getStartingTeleportNumber()
        rows = []
        vehicle_data = libsumo.inductionloop.getVehicleData
        for lid, (station, lane) in self._loops.items():
            for vid, length, entry, leave, _vtype in vehicle_data(lid):
                # A loop lists a vehicle in every step it touches it, and once more after a
                # lane change took it away: report each (loop, entry time) once.
                reported = self._reported.setdefault(vid, set())
                if entry < 0 or (lid, entry) in reported:
                    continue
                reported.add((lid, entry))
                # An inductionLoop stamps a vehicle that crossed it with the interpolated
                # crossing time plus one step, and one that appeared on it by a lane change
                # with the time of the change, a step boundary (as the instant loop does).
                steps = entry / self.step_length
                t = entry if abs(steps - round(steps)) < 1e-6 else entry - self.step_length
                try:
                    speed = libsumo.vehicle.getSpeed(vid)
                except libsumo.TraCIException:  # left the network in this very step
                    speed = length / (leave - entry) if leave > entry else MIN_SPEED
                # A vehicle that stops right behind the loop (stop-and-go) ends the step at
                # 0 m/s; a loop reports a positive speed.
                speed = max(speed, MIN_SPEED)
                seen = self._seen.setdefault(vid, set())
                kind = DOUBLE_REPORT if station in seen else PASSAGE
                seen.add(station)
                rows.append((t, station, lane, speed, length, vid, kind))
        for vid in libsumo.simulation.getArrivedIDList():
            self.arrived += 1
            self._reported.pop(vid, None)
            self._seen.pop(vid, None)
        if not rows:
            return Passages()
        cols = list(zip(*rows))
        return Passages(*cols).sorted()
