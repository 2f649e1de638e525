"""``road_sensors sumo_sensors``: sensor stations on an Eclipse SUMO scenario, published live.

SUMO runs in this process (libsumo, through ``mlkm_sumo``) and the node publishes what
``sensor_sim`` publishes: the latched layout (with the lanes of every station and the ramp
positions), one detection topic per station (lane and measured vehicle length filled in), the
ground truth of every detection (SUMO vehicle id; double reports and false alarms marked as
false alarms) and optionally /clock with the SUMO time.

* ``mode: episodes``: episode k is ``mlkm_sumo.episodes(...)``'s dataset k (the same traffic
  as ``mlkm sumo --vehicles N`` for the first): a batch of ``vehicles`` vehicles is released
  and simulated until all of them left the road, then published as EpisodeInfo STARTED (its
  window: first to last detection), the detections in passage-time order, EpisodeInfo ENDED
  with the per-station counts; then the next batch. Targets count from 0 in every episode.
* ``mode: continuous``: open-road traffic at the scenario's flow (``mlkm_sumo.PassageStream``),
  or on a road network at its draw's flow and route shares
  (``mlkm_sumo.road_networks.network_stream``), each passage published as SUMO produces it;
  no EpisodeInfo, episode_id 0 and one target numbering for the whole run in ground truth;
  ``duration`` 0 runs until stopped.

All data topics are reliable KEEP_ALL behind the shared back-pressure policy
(``mlkm_ros.publishing``), so nothing is lost; ``real_time_factor`` paces the messages by SUMO
time (0: as fast as delivery allows). The node exits 0 when every subscriber acknowledged
everything. SUMO's own errors (unknown scenario, a network that fails to build, stations that
do not fit, a SUMO failure while running) end it with one message and exit code 2.

Stamps are SUMO times, moved by ``ceil(6 * stamp_jitter)`` whole seconds so that jittered
stamps stay >= 0 (ROS times cannot be negative).
"""

from __future__ import annotations

import contextlib
import math
import sys
from dataclasses import replace
from typing import Any

import numpy as np

from mlkm_core.network import network_from_mapping
from mlkm_core.network_assoc.stations import network_stations
from mlkm_ros import conversions as conv
from mlkm_ros import lifecycle
from mlkm_ros.network_conversions import network_to_msg
from mlkm_ros.params import ParameterError
from mlkm_sumo import PassageStream, SumoDataset, SumoError, episodes, road
from mlkm_sumo.measurement import PASSAGE
from mlkm_sumo.network_sources import build_draw
from mlkm_sumo.road_networks import draw_network, generate_network, network_stream
from road_sensors.source import SensorSource
from road_sensors.sumo_params import SPECS, SumoSensorsConfig

#: Exit code of bad parameters and of SUMO's own errors.
EXIT_SUMO = 2
#: Continuous mode logs its progress every this many simulated seconds [s].
PROGRESS_EVERY = 60.0


class SumoSensorsNode(SensorSource):
    """Publishes the layout, then SUMO's detections episode by episode or as a stream."""

    #: Stopping closes SUMO on the way.
    stop_timeout = 10.0

    def __init__(self, **node_kwargs: Any) -> None:
        """``node_kwargs`` go to rclpy's Node (context, parameter_overrides, ...). Raises
        ParameterError (a refused parameter) or SumoError (scenario, network, stations)."""
        super().__init__('sumo_sensors', SPECS, SumoSensorsConfig.from_values, **node_kwargs)
        cfg: SumoSensorsConfig = self._config
        #: [ns] added to every SUMO time so that jittered stamps stay >= 0.
        self._origin_ns = conv.seconds_to_ns(math.ceil(6.0 * cfg.measurement.stamp_jitter))
        self._episodes_published = 0
        if cfg.network:
            self._open_network(cfg)
        else:
            self._open_road(cfg)
        self._start()

    def _open_road(self, cfg: SumoSensorsConfig) -> None:
        self._road = road(cfg.scenario, cfg.stations, cfg.seed, cfg.stations_at, cfg.cache_dir)
        layout = self._road.layout
        ramps = self._road.ramps
        self._open(
            layout,
            cfg.mode == 'episodes',  # a continuous source has no /road/episode publisher
            conv.layout_to_msg(
                layout,
                self._now_ns(),
                self._road.lanes,
                [r.position for r in ramps if r.kind == 'on'],
                [r.position for r in ramps if r.kind == 'off'],
            ),
        )
        what = (
            f'{cfg.episodes} episodes of {cfg.vehicles} vehicles'
            if cfg.mode == 'episodes'
            else f'continuous traffic for {cfg.duration:g} s'
            if cfg.duration
            else 'continuous traffic until stopped'
        )
        self.get_logger().info(
            f'SUMO scenario {cfg.scenario}: {layout.n_sensors} stations '
            f'({int(self._road.lanes.sum())} loops) on {layout.road_length:g} m, {what}, '
            f'seed {cfg.seed}, real_time_factor {self._rtf:g}'
        )

    def _open_network(self, cfg: SumoSensorsConfig) -> None:
        """A road network of the family ``cfg.network`` drawn for ``cfg.seed`` with
        ``cfg.vehicles`` vehicles (``mlkm sumo --network``'s draw), published in the network
        form of the layout with its links' shapes."""
        self._draw = draw_network(cfg.network, cfg.seed, vehicles=cfg.vehicles)
        self._built = build_draw(self._draw, cfg.cache_dir)
        self._net = network_from_mapping(self._built.mapping, f'{cfg.network} seed {cfg.seed}')
        episodic = cfg.mode == 'episodes'
        self._open(
            network_stations(self._net), episodic, network_to_msg(self._net, self._now_ns())
        )
        what = (
            f'{cfg.episodes} episodes of {cfg.vehicles} vehicles'
            if episodic
            else f'continuous traffic at {self._draw.flow:.0f} vehicles/h '
            + (f'for {cfg.duration:g} s' if cfg.duration else 'until stopped')
        )
        self.get_logger().info(
            f'SUMO network {cfg.network} seed {cfg.seed}: {self._net.n_stations} stations on '
            f'{len(self._net.links)} links, {what}, real_time_factor {self._rtf:g}'
        )

    # --- the run --------------------------------------------------------------------------
    def _publish_all(self) -> bool:
        try:
            return self._run_episodes() if self._config.mode == 'episodes' else self._stream()
        except SumoError as exc:
            self._fail(f'SUMO failed: {exc}', EXIT_SUMO)
            return False

    def _summary(self) -> str:
        if self._config.mode == 'episodes':
            return f' in {self._episodes_published} episodes'
        return ''

    def _run_episodes(self) -> bool:
        cfg: SumoSensorsConfig = self._config
        if cfg.network:
            return self._run_network_episodes(cfg)
        batches = episodes(cfg.scenario, cfg.vehicles, cfg.episodes, **cfg.sumo_options())
        with contextlib.closing(batches):  # an early stop closes SUMO
            for k, dataset in enumerate(batches):
                if self._interrupted() or not self._publish_episode(k, dataset):
                    return False
        return True

    def _run_network_episodes(self, cfg: SumoSensorsConfig) -> bool:
        """Episode k: the network's traffic with SUMO and the measurement seeded seed + k
        (episode 0 is ``mlkm sumo --network <family> --seed <seed>``'s run)."""
        for k in range(cfg.episodes):
            draw = replace(self._draw, seed=self._draw.seed + k)
            ds = generate_network(draw, cfg.cache_dir, cfg.measurement, cfg.step_length)
            if ds.mapping != self._built.mapping:
                raise SumoError(f'episode {k}: SUMO built another network for seed {draw.seed}')
            if self._interrupted() or not self._publish_episode(k, _NetworkEpisode(ds)):
                return False
        return True

    def _publish_episode(self, k: int, ds: SumoDataset) -> bool:
        """Publish one episode; False when interrupted."""
        det = ds.detections
        if ds.n_targets == 0:
            self.get_logger().warning(
                f'episode {k}: no vehicle was detected (all passages missed); not published'
            )
            return True
        stamps_ns = np.maximum(conv.seconds_to_ns_array(det.stamp) + self._origin_ns, 0)
        start_ns, end_ns = int(stamps_ns.min()), int(stamps_ns.max())
        if not self._episode_started(k, ds.n_targets, start_ns, end_ns):
            return False
        order = np.lexsort((det.lane, det.sensor_index, det.stamp)).tolist()
        station, lane = det.sensor_index.tolist(), det.lane.tolist()
        speed, length = det.velocity.tolist(), det.length.tolist()
        target, true_speed = det.target.tolist(), ds.true_speed.tolist()
        stamps, t_ns, vehicle = det.stamp.tolist(), stamps_ns.tolist(), ds.vehicle.tolist()
        for i in order:
            if self._stop.is_set():
                return False
            self._pace(stamps[i])
            if not self._publish_one(
                k, station[i], t_ns[i], speed[i], target[i], true_speed[i], lane[i], length[i],
                vehicle[i],
            ):  # fmt: skip
                return False
        self._published += len(order)
        ended = self._episode_ended(k, ds.n_targets, start_ns, end_ns, det.sensor_index)
        if ended:
            self._episodes_published += 1
            s = ds.stats
            self.get_logger().info(
                f'episode {k}: {len(order)} detections of {ds.n_targets} vehicles published '
                f'({s["double_reports"]} double reports, {s["missed"]} missed, '
                f'{s["false_alarms"]} false alarms; {s["simulated_s"]:.0f} s simulated)'
            )
        return ended

    def _stream(self) -> bool:
        cfg: SumoSensorsConfig = self._config
        if cfg.network:
            stream = network_stream(
                self._draw, cfg.duration, cfg.measurement, step_length=cfg.step_length,
                road=self._built,
            )  # fmt: skip
        else:
            stream = PassageStream(cfg.scenario, duration=cfg.duration, **cfg.sumo_options())
        targets: dict[str, int] = {}  # SUMO id -> target id of this run
        next_log = PROGRESS_EVERY
        passages = iter(stream)
        with contextlib.closing(passages):  # an early stop closes SUMO
            for p in passages:
                if self._stop.is_set():
                    return False
                self._pace(p.time)
                target = targets.setdefault(p.vehicle, len(targets)) if p.kind == PASSAGE else -1
                t_ns = max(conv.seconds_to_ns(p.time) + self._origin_ns, 0)
                if not self._publish_one(
                    0, p.station, t_ns, p.speed, target, p.true_speed, p.lane, p.length,
                    p.vehicle,
                ):  # fmt: skip
                    return False
                self._published += 1
                if p.time >= next_log:
                    next_log += PROGRESS_EVERY
                    self.get_logger().info(
                        f'{p.time:.0f} s simulated: {self._published} detections of '
                        f'{len(targets)} vehicles published'
                    )
        return True


class _NetworkEpisode:
    """A network run as ``_publish_episode`` reads an episode: station ids are the network's
    station indexes (``mlkm sumo --network`` numbers them so)."""

    def __init__(self, ds) -> None:
        self.detections = ds.detections()
        self.n_targets = ds.n_targets
        self.true_speed = ds.true_speed
        self.vehicle = ds.vehicle
        self.stats = ds.stats


def main(args: list[str] | None = None) -> int:
    # Ctrl-C and SIGTERM only end the spin, also while the node is set up or waits for
    # subscribers; the publishing thread shuts the context down when it is done.
    return lifecycle.run_node(
        'sumo_sensors',
        SumoSensorsNode,
        args,
        refusals=[((ParameterError, SumoError), 'error: ', EXIT_SUMO)],
        finish=lambda node: node.finish('sumo_sensors', 'error: '),
    )


if __name__ == '__main__':
    sys.exit(main())
