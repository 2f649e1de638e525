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
ever (``mlkm_core.simulator.simulate_stream``: the paper's U(t_min, t_max) spacing, or a
Poisson stream at ``arrival_rate``), stamps start at 0 and never go down, no EpisodeInfo is
published (there is no /road/episode publisher at all, so an association node in mode auto
tracks the stream), ground truth carries episode 0. ``duration`` [s] of stamp time ends it
(0 = for ever, until Ctrl-C).
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Any

import numpy as np
import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.publisher import Publisher
from rosgraph_msgs.msg import Clock

from mlkm_core.simulator import (
    StreamDetection,
    simulate_episodes,
    simulate_stream,
    stream_layout,
    stream_origin,
    time_window,
)
from mlkm_core.types import Dataset
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_ros.params import ParameterError, declare_parameters
from mlkm_ros.publishing import PublishTimeout, ReliablePublisher, total_stats, wait_all_acked
from road_sensor_msgs.msg import Detection, EpisodeInfo, GroundTruth, SensorLayout
from road_sensors.sim_params import _NODE_SPECS, SensorSimConfig, _sim_specs

#: The parameter tables live in road_sensors.sim_params (re-exported for the param-file test).
__all__ = ['SensorSimConfig', 'SensorSimNode', '_NODE_SPECS', '_sim_specs', 'main']


class SensorSimNode(Node):
    """Publishes the layout, then episode after episode of simulated detections."""

    def __init__(self, **node_kwargs: Any) -> None:
        """``node_kwargs`` go to rclpy's Node (context, parameter_overrides, ...)."""
        super().__init__('sensor_sim', **node_kwargs)
        values = declare_parameters(self, _sim_specs() + _NODE_SPECS, self._on_change)
        self._config: SensorSimConfig = SensorSimConfig.from_values(values)
        self._rtf: float = self._config.real_time_factor
        cfg = self._config
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
        self._stop = threading.Event()
        self._layout_pub: Publisher = self.create_publisher(
            SensorLayout, qos.LAYOUT_TOPIC, qos.LAYOUT_QOS
        )
        # A continuous source has no /road/episode publisher at all (receivers in mode auto
        # tell the two kinds of source apart by it).
        self._episode_pub: ReliablePublisher | None = (
            None
            if self._continuous
            else self._reliable(
                self.create_publisher(EpisodeInfo, qos.EPISODE_TOPIC, qos.EPISODE_QOS)
            )
        )
        self._truth_pub = self._reliable(
            self.create_publisher(GroundTruth, qos.GROUND_TRUTH_TOPIC, qos.GROUND_TRUTH_QOS)
        )
        self._det_pubs: list[ReliablePublisher] = [
            self._reliable(
                self.create_publisher(Detection, qos.detections_topic(name), qos.DETECTIONS_QOS)
            )
            for name in layout.names
        ]
        self._clock_pub: Publisher | None = (
            self.create_publisher(Clock, qos.CLOCK_TOPIC, qos.CLOCK_QOS)
            if cfg.publish_clock
            else None
        )
        self._anchor: tuple[float, float] | None = None  # (passage time, wall time)
        self._done = threading.Event()
        self._error: str | None = None
        self._published = 0
        self._layout_pub.publish(conv.layout_to_msg(layout, self._now_ns()))
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
        self._thread = threading.Thread(target=self._run, name='sensor_sim', daemon=True)
        self._thread.start()

    # --- parameters -----------------------------------------------------------------------
    def _on_change(self, changed: dict[str, Any]) -> None:
        if 'real_time_factor' in changed:
            self._rtf = float(changed['real_time_factor'])
            self._anchor = None

    # --- publishing -----------------------------------------------------------------------
    def _reliable(self, publisher: Publisher) -> ReliablePublisher:
        return ReliablePublisher(publisher, self.context, self._stop)

    def _interrupted(self) -> bool:
        """A stop request or Ctrl-C (which shuts the context down under the worker thread)."""
        return self._stop.is_set() or not self.context.ok()

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _subscription_counts(self) -> tuple[int, int] | None:
        """(fewest subscribers of a detection topic, ground-truth subscribers); None when
        interrupted (the context may vanish between two counts)."""
        try:
            least = min(p.publisher.get_subscription_count() for p in self._det_pubs)
            truth = self._truth_pub.publisher.get_subscription_count()
        except RCLError:
            if self._interrupted():
                return None
            raise
        return least, truth

    def _wait_for_subscribers(self) -> bool:
        cfg = self._config
        deadline = None if cfg.wait_timeout <= 0 else time.monotonic() + cfg.wait_timeout
        announced = False
        while not self._interrupted():
            counts = self._subscription_counts()
            if counts is None:
                return False
            least, truth = counts
            if least >= cfg.wait_for_subscribers and truth >= cfg.wait_for_truth_subscribers:
                return True
            if not announced:
                self.get_logger().info(
                    f'waiting for {cfg.wait_for_subscribers} subscriber(s) on every detection '
                    f'topic and {cfg.wait_for_truth_subscribers} on ground truth'
                )
                announced = True
            if deadline is not None and time.monotonic() > deadline:
                self._error = (
                    f'no subscribers after {cfg.wait_timeout:g} s: detection topics have '
                    f'{least} (need {cfg.wait_for_subscribers}), ground truth has '
                    f'{truth} (need {cfg.wait_for_truth_subscribers})'
                )
                return False
            self._stop.wait(0.05)
        return False

    def _pace(self, stamp: float) -> None:
        """Sleep until the wall time of passage time ``stamp`` (real_time_factor > 0)."""
        rtf = self._rtf
        if rtf <= 0:
            return
        if self._anchor is None:
            self._anchor = (stamp, time.monotonic())
        t_sim, t_wall = self._anchor
        delay = t_wall + (stamp - t_sim) / rtf - time.monotonic()
        if delay > 0:
            self._stop.wait(delay)

    def _reliable_publishers(self) -> list[ReliablePublisher]:
        extra = [] if self._episode_pub is None else [self._episode_pub]
        return [*self._det_pubs, self._truth_pub, *extra]

    def _wait_acked(self) -> bool:
        return wait_all_acked(self._reliable_publishers(), self._config.ack_timeout)

    def _run(self) -> None:
        try:
            if not self._wait_for_subscribers():
                return
            if self._config.start_delay > 0:
                self._stop.wait(self._config.start_delay)
            self._anchor = None
            if self._continuous:
                if not self._publish_stream():
                    return
            for k, dataset in enumerate(self._datasets):
                if self._interrupted() or not self._publish_episode(k, dataset):
                    return
            if not self._wait_acked() and not self._interrupted():
                self.get_logger().warning('not every message was acknowledged in time')
            if self._interrupted():
                return
            flow = total_stats(self._reliable_publishers())
            where = (
                f'of {self._stream_stats.get("vehicles", 0)} vehicles generated, continuous'
                if self._continuous
                else f'in {len(self._datasets)} episodes'
            )
            self.get_logger().info(
                f'published {self._published} detections {where} '
                f'(waited {flow["waited"]:g} s for subscribers: {flow["window_waits"]} '
                f'flow-control waits, {flow["retries"]} refused publishes retried)'
            )
        except PublishTimeout as exc:
            self._error = str(exc)
        except Exception as exc:  # noqa: BLE001 - reported, and the process exits nonzero
            if not self._interrupted():
                self._error = f'{type(exc).__name__}: {exc}'
        finally:
            self._done.set()
            if not self._config.keep_running or self._error:
                rclpy.try_shutdown(context=self.context)

    def _publish_stream(self) -> bool:
        """Continuous mode: detections of the endless road until ``duration``; False when
        interrupted."""
        cfg = self._config
        ids = [int(s) for s in self._layout.sensor_ids]
        positions = [float(p) for p in self._layout.positions]
        det_pubs, truth_pub, clock_pub = self._det_pubs, self._truth_pub, self._clock_pub
        stream = simulate_stream(
            cfg.sim, cfg.seed, cfg.arrival_rate, cfg.duration, self._stream_stats
        )
        last_clock = None
        next_report = 60.0
        det: StreamDetection
        for det in stream:
            if self._stop.is_set():
                return False
            self._pace(det.stamp)
            s, t_ns = det.sensor_index, conv.seconds_to_ns(det.stamp)
            if clock_pub is not None and (last_clock is None or t_ns - last_clock >= 10**7):
                clock_pub.publish(Clock(clock=conv.ns_to_time(t_ns)))
                last_clock = t_ns
            if not det_pubs[s].publish(
                conv.detection_to_msg(ids[s], t_ns, positions[s], det.velocity)
            ) or not truth_pub.publish(
                conv.ground_truth_to_msg(0, ids[s], t_ns, det.target, det.true_velocity)
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
        layout = dataset.layout
        det = dataset.detections
        origin = self._origin_ns
        start, end = time_window(dataset)
        start_ns, end_ns = conv.seconds_to_ns(start) + origin, conv.seconds_to_ns(end) + origin
        if not self._episode_pub.publish(
            conv.episode_started_msg(k, dataset.n_targets, start_ns, end_ns, self._now_ns())
        ):
            return False
        order = np.lexsort((det.sensor_index, det.stamp))  # passage time, then position
        sensor_index = det.sensor_index[order].tolist()
        stamps = det.stamp[order].tolist()
        stamps_ns = (conv.seconds_to_ns_array(det.stamp[order]) + origin).tolist()
        velocity = det.velocity[order].tolist()
        target = (det.target[order] if det.target is not None else np.full(len(det), -1)).tolist()
        ids = [int(s) for s in layout.sensor_ids]
        positions = [float(p) for p in layout.positions]
        det_pubs, truth_pub, clock_pub = self._det_pubs, self._truth_pub, self._clock_pub
        last_clock = None
        for i in range(len(stamps)):
            if self._stop.is_set():
                return False
            self._pace(stamps[i])
            s, t_ns = sensor_index[i], stamps_ns[i]
            if clock_pub is not None and (last_clock is None or t_ns - last_clock >= 10**7):
                clock_pub.publish(Clock(clock=conv.ns_to_time(max(t_ns, 0))))
                last_clock = t_ns
            if not det_pubs[s].publish(
                conv.detection_to_msg(ids[s], t_ns, positions[s], velocity[i])
            ) or not truth_pub.publish(
                conv.ground_truth_to_msg(k, ids[s], t_ns, target[i], velocity[i])
            ):
                return False
        self._published += len(stamps)
        counts = np.bincount(det.sensor_index, minlength=layout.n_sensors)
        # No acknowledgement wait here (Fast DDS acknowledges on its heartbeat period, ~3 s):
        # ENDED may overtake detections on other topics; its counts tell the receivers how
        # many to expect. The run ends with a wait for every acknowledgement.
        ended = self._episode_pub.publish(
            conv.episode_ended_msg(
                k,
                dataset.n_targets,
                start_ns,
                end_ns,
                self._now_ns(),
                {ids[s]: int(counts[s]) for s in range(layout.n_sensors)},
            )
        )
        if ended:
            self.get_logger().info(
                f'episode {k}: {len(stamps)} detections of {dataset.n_targets} targets published'
            )
        return ended

    # --- lifecycle ------------------------------------------------------------------------
    @property
    def error(self) -> str | None:
        return self._error

    def stop(self) -> None:
        """Interrupt the publishing thread and wait for it (its waits end within ~0.2 s)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)

    def destroy_node(self) -> None:
        self.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    try:
        node = SensorSimNode()
    except ParameterError as exc:
        print(f'sensor_sim: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.stop()  # first: the thread must not report an interruption as an error
        error = node.error
        node.destroy_node()
        rclpy.try_shutdown()
    if error:
        print(f'sensor_sim: {error}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
