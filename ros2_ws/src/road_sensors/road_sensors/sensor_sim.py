"""``road_sensors sensor_sim``: simulated road-side sensors publishing live.

Episode k is dataset k of the core's ``simulate_episodes(config, seed, episodes, gap)``, so
the same seed gives the same datasets as the offline core. For each episode the node
publishes EpisodeInfo STARTED, then every detection in passage-time order across the whole
road (each on its sensor's topic, header.stamp = passage time) with its GroundTruth, then
EpisodeInfo ENDED with the per-sensor counts. ``real_time_factor`` > 0 paces the messages by
passage time; 0 publishes as fast as delivery allows. All data topics are reliable KEEP_ALL
and the node waits for its subscribers and for their acknowledgements, so nothing is lost:
every publisher applies the shared back-pressure policy (``mlkm_ros.publishing``), so a slow
subscriber slows the node down instead of breaking it.

Stamps are the core's passage times moved by a whole number of seconds
(``mlkm_core.simulator.stream_origin``) so that the stream starts at t >= 0 (ROS times cannot
be negative); relative times, hence every association result, are the core's.

``mode:=continuous``: an open road instead of episodes. Vehicles of the same model enter for
ever (``mlkm_core.simulator_stream.simulate_stream``: the paper's U(t_min, t_max) spacing, or a
Poisson stream at ``arrival_rate``), stamps start at 0 and never go down, no EpisodeInfo is
published (there is no /road/episode publisher at all, so an association node in mode auto
tracks the stream), ground truth carries episode 0. ``duration`` [s] of stamp time ends it
(0 = for ever, until Ctrl-C).
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from mlkm_core.simulator import simulate_episodes, stream_origin, time_window
from mlkm_core.simulator_stream import StreamDetection, simulate_stream, stream_layout
from mlkm_core.types import Dataset
from mlkm_ros import conversions as conv
from mlkm_ros import lifecycle
from road_sensors.sim_params import _NODE_SPECS, SensorSimConfig, _sim_specs
from road_sensors.source import SensorSource

#: The parameter tables live in road_sensors.sim_params (re-exported for the param-file test).
__all__ = ['SensorSimConfig', 'SensorSimNode', '_NODE_SPECS', '_sim_specs', 'main']


class SensorSimNode(SensorSource):
    """Publishes the layout, then episode after episode of simulated detections."""

    def __init__(self, **node_kwargs: Any) -> None:
        """``node_kwargs`` go to rclpy's Node (context, parameter_overrides, ...)."""
        super().__init__(
            'sensor_sim', _sim_specs() + _NODE_SPECS, SensorSimConfig.from_values, **node_kwargs
        )
        cfg: SensorSimConfig = self._config
        self._continuous = cfg.mode == 'continuous'
        self._datasets: list[Dataset] = []
        self._stream_stats: dict[str, int] = {}
        if self._continuous:
            layout = stream_layout(cfg.sim, cfg.seed)
            self._origin_ns = 0  # simulate_stream starts at 0
        else:
            self._datasets = simulate_episodes(cfg.sim, cfg.seed, cfg.episodes, cfg.episode_gap)
            #: [ns] added to every passage time, so that the stream starts at t >= 0.
            self._origin_ns: int = conv.seconds_to_ns(stream_origin(self._datasets))
            layout = self._datasets[0].layout
        self._layout = layout
        self._open(layout, not self._continuous, conv.layout_to_msg(layout, self._now_ns()))
        if self._continuous:
            length = f'{cfg.duration:g} s' if cfg.duration > 0 else 'for ever'
            spacing = (
                f'Poisson arrivals at {cfg.arrival_rate:g}/s'
                if cfg.arrival_rate > 0
                else f'spacing U({cfg.sim.start_increment_min:g}, '
                f'{cfg.sim.start_increment_max:g}) s'
            )
            what = f'continuous traffic ({spacing}) {length}'
        else:
            what = f'{cfg.episodes} episodes of {cfg.sim.n_targets} targets'
        self.get_logger().info(
            f'{layout.n_sensors} sensors on {layout.road_length:g} m, {what}, seed {cfg.seed}, '
            f'real_time_factor {self._rtf:g}'
            + (f', stamps start at +{self._origin_ns / 1e9:g} s' if self._origin_ns else '')
        )
        self._start()

    # --- publishing -----------------------------------------------------------------------
    def _publish_all(self) -> bool:
        if self._continuous:
            return self._publish_stream()
        for k, dataset in enumerate(self._datasets):
            if self._interrupted() or not self._publish_episode(k, dataset):
                return False
        return True

    def _summary(self) -> str:
        if self._continuous:
            return f' of {self._stream_stats.get("vehicles", 0)} vehicles generated, continuous'
        return f' in {len(self._datasets)} episodes'

    def _publish_stream(self) -> bool:
        """Continuous mode: detections of the endless road until ``duration``; False when
        interrupted."""
        cfg: SensorSimConfig = self._config
        stream = simulate_stream(
            cfg.sim, cfg.seed, cfg.arrival_rate, cfg.duration, self._stream_stats
        )
        self._last_clock = None
        next_report = 60.0
        det: StreamDetection
        for det in stream:
            if self._stop.is_set():
                return False
            self._pace(det.stamp)
            if not self._publish_one(
                0,
                det.sensor_index,
                conv.seconds_to_ns(det.stamp),
                det.velocity,
                det.target,
                det.true_velocity,
            ):
                return False
            self._published += 1
            if det.stamp >= next_report:
                next_report += 60.0
                self.get_logger().info(
                    f'continuous: {self._published} detections published up to '
                    f't = {det.stamp:.0f} s'
                )
        return True

    def _publish_episode(self, k: int, dataset: Dataset) -> bool:
        """Publish one episode; False when interrupted."""
        det = dataset.detections
        origin = self._origin_ns
        start, end = time_window(dataset)
        start_ns, end_ns = conv.seconds_to_ns(start) + origin, conv.seconds_to_ns(end) + origin
        if not self._episode_started(k, dataset.n_targets, start_ns, end_ns):
            return False
        order = np.lexsort((det.sensor_index, det.stamp))  # passage time, then position
        sensor_index = det.sensor_index[order].tolist()
        stamps = det.stamp[order].tolist()
        stamps_ns = (conv.seconds_to_ns_array(det.stamp[order]) + origin).tolist()
        velocity = det.velocity[order].tolist()
        target = (det.target[order] if det.target is not None else np.full(len(det), -1)).tolist()
        self._last_clock = None
        for i in range(len(stamps)):
            if self._stop.is_set():
                return False
            self._pace(stamps[i])
            if not self._publish_one(
                k, sensor_index[i], stamps_ns[i], velocity[i], target[i], velocity[i]
            ):
                return False
        self._published += len(stamps)
        ended = self._episode_ended(k, dataset.n_targets, start_ns, end_ns, det.sensor_index)
        if ended:
            self.get_logger().info(
                f'episode {k}: {len(stamps)} detections of {dataset.n_targets} targets published'
            )
        return ended


def main(args: list[str] | None = None) -> int:
    # Ctrl-C and SIGTERM only end the spin, also while the node is set up or waits for
    # subscribers; the publishing thread shuts the context down when it is done.
    return lifecycle.run_node(
        'sensor_sim', SensorSimNode, args, finish=lambda node: node.finish('sensor_sim')
    )


if __name__ == '__main__':
    sys.exit(main())
