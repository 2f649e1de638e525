"""``road_sensors log_source``: a recorded detector log replayed into the graph as a live feed.

The log is the product's detections CSV (what ``mlkm associate --input`` reads,
``mlkm_core.csvio``), the road a layout file (``mlkm_core.layout_file``: station ids, names,
positions, lanes, ramps) or a road network's (``mlkm_core.network_file``: links, junctions,
stations on links; the SensorLayout then has its network form, each detection the position
along its station's link). The node publishes what the other sources publish: the latched
layout from the layout file (lanes, entries, exits), every valid row of the log on its
station's topic in stamp order (lane and vehicle length where the log has those columns), and
the ground truth of every row when the log has a ``target_id`` column (without it the
ground-truth topic stays silent).

* ``mode: episodes``: the whole log is one episode (id 0): EpisodeInfo STARTED (its window:
  first to last stamp), the detections, EpisodeInfo ENDED with the per-station counts. Its
  ``n_targets`` is the largest number of detections at one station, what ``mlkm associate``
  assumes without ``--targets``: the log's truth is never used for the association.
* ``mode: continuous``: the rows as a stream, no EpisodeInfo, episode_id 0 in ground truth.

``real_time_factor`` paces the rows by their stamps (0: as fast as delivery allows); nothing
is lost either way. ROS stamps cannot be negative: a log with negative stamps is published
``ceil(-first stamp)`` whole seconds later, which leaves every time difference, hence every
association result, as in the file (the node logs the shift).

Refused at start, with one message and exit code 2: a parameter, a log or layout file that
cannot be read, a log whose sensor ids are not all in the layout file or sit at other
positions than it gives. Invalid rows (a value out of bounds, a duplicate, a field that is not
a number) are the user's data: they are skipped, counted and logged with their reasons, and
the valid rows are published.
"""

from __future__ import annotations

import math
import sys
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from mlkm_core.csvio import InputError, RowProblem, read_detections
from mlkm_core.layout_file import LayoutFileError, RoadLayout, read_layout_file
from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc.stations import network_stations
from mlkm_core.network_file import is_network_file, read_network_file
from mlkm_core.types import UNKNOWN_LANE, Layout
from mlkm_ros import conversions as conv
from mlkm_ros import lifecycle
from mlkm_ros.network_conversions import network_to_msg
from mlkm_ros.params import ParameterError
from road_sensors.log_params import SPECS, LogSourceConfig
from road_sensors.source import SensorSource

#: Exit code of bad parameters and of a log or layout file that cannot be replayed.
EXIT_REFUSED = 2
#: A log position may differ from the layout file's by this much (1 mm: the CSV's usual
#: three decimals) [m].
POSITION_TOLERANCE = 1e-3
#: How many invalid rows the log lists one by one (all are counted).
LISTED = 10
#: Continuous mode logs its progress every this much log time [s].
PROGRESS_EVERY = 60.0

__all__ = ['SPECS', 'LogSourceError', 'LogSourceNode', 'Replay', 'load_replay', 'main']


class LogSourceError(ValueError):
    """A log or layout file that cannot be replayed; the message says which and why."""


@dataclass(frozen=True)
class Replay:
    """A log matched to its layout file, the valid rows in publishing (stamp) order."""

    road: RoadLayout | None  # the single road of the layout file, or None on a network
    network: RoadNetwork | None  # the road network of the layout file, or None
    station: np.ndarray  # station index in the layout file
    stamp_ns: np.ndarray  # published stamp: the log's plus ``shift_s`` [ns], >= 0
    velocity: np.ndarray  # [m/s]
    target: np.ndarray | None  # the log's target_id (-1 false alarm); None: no truth column
    lane: np.ndarray  # -1 unknown
    length: np.ndarray  # [m], NaN unknown
    shift_s: int  # whole seconds added to the log's stamps [s]
    first_stamp: float  # the log's own first stamp [s]
    rows: int  # data rows of the log, invalid ones included
    problems: list[RowProblem]  # the invalid rows, in file order
    columns: tuple[str, ...]  # the optional columns the log has (target_id, lane, length_m)

    @property
    def stations(self) -> Layout:
        """The stations: the road's, or the network's (``NetworkStations``)."""
        return self.road.layout if self.network is None else network_stations(self.network)

    @property
    def lanes(self) -> np.ndarray:
        """Lanes per station, 0 unknown."""
        if self.network is None:
            return np.asarray(self.road.lanes, np.int64)
        return np.asarray(self.network.station_lanes, np.int64)

    @property
    def n_targets(self) -> int:
        """The largest number of detections at one station."""
        return int(np.bincount(self.station).max())


def load_replay(log: str, layout: str) -> Replay:
    """Read the layout file (either form: one road or a road network) and the log (invalid
    rows skipped) and match their sensors; raises LogSourceError (module docstring)."""
    road, network = None, None
    try:
        if is_network_file(layout):
            network = read_network_file(layout)
        else:
            road = read_layout_file(layout)
    except LayoutFileError as exc:
        raise LogSourceError(f'layout file {exc}') from None
    try:
        data = read_detections(log, skip_invalid=True, network=network)
    except InputError as exc:  # InvalidRows too: not one row is valid
        raise LogSourceError(f'log {exc}') from None
    if network is not None:  # csvio placed every row at its network station
        return _replay(road, network, data, data.detections.sensor_index)
    by_id = {int(s): i for i, s in enumerate(road.layout.sensor_ids)}
    log_ids = [int(s) for s in data.layout.sensor_ids]
    unknown = [s for s in log_ids if s not in by_id]
    if unknown:
        listed = ', '.join(str(s) for s in sorted(unknown)[:LISTED])
        more = f' and {len(unknown) - LISTED} more' if len(unknown) > LISTED else ''
        known = ', '.join(str(int(s)) for s in sorted(road.layout.sensor_ids)[:LISTED])
        raise LogSourceError(
            f'log {log}: sensor id(s) {listed}{more} not in the layout file {layout} '
            f'(its ids: {known}{", ..." if len(by_id) > LISTED else ""})'
        )
    for sid, x in zip(log_ids, data.layout.positions.tolist(), strict=True):
        at = float(road.layout.positions[by_id[sid]])
        if not abs(x - at) <= POSITION_TOLERANCE:
            raise LogSourceError(
                f'log {log}: sensor {sid} is at position_m {x}, the layout file {layout} '
                f'puts it at {at} m (they may differ by {POSITION_TOLERANCE * 1000:g} mm)'
            )
    to_road = np.array([by_id[s] for s in log_ids], np.int64)
    return _replay(road, None, data, to_road[data.detections.sensor_index])


def _replay(road, network, data, station: np.ndarray) -> Replay:
    """The Replay of ``data`` read from a log, ``station`` the index of each of its
    detections among the layout file's stations."""
    det = data.detections
    n = len(det)
    first = float(det.stamp.min())
    shift = math.ceil(-first) if first < 0 else 0
    stamp_ns = conv.seconds_to_ns_array(det.stamp) + shift * conv.NS_PER_S
    lane = det.lane if det.lane is not None else np.full(n, UNKNOWN_LANE, np.int64)
    length = det.length if det.length is not None else np.full(n, np.nan)
    order = np.lexsort((np.arange(n), lane, station, stamp_ns))
    return Replay(
        road=road,
        network=network,
        station=station[order],
        stamp_ns=np.maximum(stamp_ns[order], 0),
        velocity=det.velocity[order],
        target=None if det.target is None else det.target[order],
        lane=lane[order],
        length=length[order],
        shift_s=shift,
        first_stamp=first,
        rows=data.n_rows,
        problems=[data.problems[k] for k in sorted(data.problems)],
        columns=tuple(c for c in ('target_id', 'lane', 'length_m') if c in data.header),
    )


def describe_problems(problems: list[RowProblem]) -> str:
    """'3 invalid rows skipped (2 malformed, 1 duplicate): line 5: ...; ...'."""
    n = len(problems)
    reasons = ', '.join(f'{c} {r}' for r, c in Counter(p.reason for p in problems).most_common())
    listed = '; '.join(f'line {p.line}: {p.message}' for p in problems[:LISTED])
    more = f'; ... and {n - LISTED} more' if n > LISTED else ''
    return f'{n} invalid row{"s" if n != 1 else ""} skipped ({reasons}): {listed}{more}'


class LogSourceNode(SensorSource):
    """Publishes the layout file, then the log's rows as one episode or as a stream."""

    def __init__(self, **node_kwargs: Any) -> None:
        """``node_kwargs`` go to rclpy's Node (context, parameter_overrides, ...). Raises
        ParameterError (a refused parameter) or LogSourceError (the files)."""
        super().__init__('log_source', SPECS, LogSourceConfig.from_values, **node_kwargs)
        cfg: LogSourceConfig = self._config
        self._replay = r = load_replay(cfg.log, cfg.layout)
        self._episodic = cfg.mode == 'episodes'
        road, stations = r.road, r.stations
        if r.network is not None:
            layout_msg = network_to_msg(r.network, self._now_ns())
        else:
            layout_msg = conv.layout_to_msg(
                road.layout, self._now_ns(), road.lanes, road.entries, road.exits
            )
        self._open(
            stations,
            self._episodic,  # a continuous source has no /road/episode publisher
            layout_msg,
            truth=r.target is not None,
        )
        log = self.get_logger()
        last = r.stamp_ns[-1] / conv.NS_PER_S - r.shift_s
        log.info(
            f'log {cfg.log}: {r.station.size} detections at {np.unique(r.station).size} of '
            f'{stations.n_sensors} stations ({cfg.layout}), stamps {r.first_stamp:g} .. '
            f'{last:g} s, columns: '
            f'{", ".join(r.columns) or "no optional ones"}; '
            + ('one episode' if self._episodic else 'a stream')
            + f', real_time_factor {self._rtf:g}'
            + ('' if r.target is not None else '; no target_id column: no ground truth')
        )
        if r.problems:
            log.warning(f'log {cfg.log}: {describe_problems(r.problems)}')
        if r.shift_s:
            log.warning(
                f'log {cfg.log}: stamps from {r.first_stamp:g} s; ROS stamps cannot be '
                f'negative, so every row is published {r.shift_s} s later (header.stamp = '
                f'stamp_s + {r.shift_s})'
            )
        counts = r.lanes[r.station]
        beyond = int(np.count_nonzero((counts > 0) & (r.lane >= counts)))
        if beyond:
            log.warning(
                f'log {cfg.log}: {beyond} rows have a lane beyond the lane count of their station '
                'in the layout file; receivers refuse them (lane_out_of_range)'
            )
        self._start()

    # --- the run --------------------------------------------------------------------------
    def _summary(self) -> str:
        r = self._replay
        skipped = f', {len(r.problems)} invalid rows skipped' if r.problems else ''
        return f' of {r.rows} rows{skipped}' + (' in 1 episode' if self._episodic else '')

    def _publish_all(self) -> bool:
        r = self._replay
        t_ns = r.stamp_ns.tolist()
        start_ns, end_ns = t_ns[0], t_ns[-1]
        if self._episodic and not self._episode_started(0, r.n_targets, start_ns, end_ns):
            return False
        station, speed = r.station.tolist(), r.velocity.tolist()
        lane, length = r.lane.tolist(), r.length.tolist()
        target = [-1] * len(t_ns) if r.target is None else r.target.tolist()
        next_log = start_ns / conv.NS_PER_S + PROGRESS_EVERY
        for i, ns in enumerate(t_ns):
            if self._stop.is_set():
                return False
            stamp = ns / conv.NS_PER_S
            self._pace(stamp)
            if not self._publish_one(
                0, station[i], ns, speed[i], target[i], speed[i], lane[i], length[i]
            ):
                return False
            self._published += 1
            if not self._episodic and stamp >= next_log:
                next_log += PROGRESS_EVERY
                self.get_logger().info(f'{self._published} of {len(t_ns)} rows published')
        if not self._episodic:
            return True
        ended = self._episode_ended(0, r.n_targets, start_ns, end_ns, r.station)
        if ended:
            self.get_logger().info(
                f'episode 0: {len(t_ns)} detections published (n_targets {r.n_targets})'
            )
        return ended


def main(args: list[str] | None = None) -> int:
    # Ctrl-C and SIGTERM only end the spin, also while the node reads the log or waits for
    # subscribers; the publishing thread shuts the context down when it is done.
    return lifecycle.run_node(
        'log_source',
        LogSourceNode,
        args,
        refusals=[((ParameterError, LogSourceError), 'error: ', EXIT_REFUSED)],
        finish=lambda node: node.finish('log_source', 'error: '),
    )


if __name__ == '__main__':
    sys.exit(main())
