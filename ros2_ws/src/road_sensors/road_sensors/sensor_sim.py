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
"""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.publisher import Publisher
from rosgraph_msgs.msg import Clock

from mlkm_core.simulator import SimConfig, simulate_episodes, stream_origin, time_window
from mlkm_core.types import Dataset
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_ros.params import ParameterError, ParamSpec, declare_parameters, non_negative
from mlkm_ros.publishing import PublishTimeout, ReliablePublisher, total_stats, wait_all_acked
from road_sensor_msgs.msg import Detection, EpisodeInfo, GroundTruth, SensorLayout

#: Descriptions (with units) and inclusive ranges of the simulator's settings.
_SIM_DOCS: dict[str, tuple[str, float | None, float | None]] = {
    'road_length': ('road length D [m]', 1e-3, 1e9),
    'n_sensors': ('number of sensors N_S [-]', 1, 100000),
    'n_targets': ('number of targets N_A per episode [-]', 1, 10000000),
    'velocity_mean': ('mean cruise speed mu [m/s]', 1e-6, 1e6),
    'velocity_std': ('std of the cruise speed sigma [m/s]', 0.0, 1e6),
    'start_increment_min': ('t_min of the start-time increment U(t_min, t_max) [s]', -1e6, 1e6),
    'start_increment_max': ('t_max of the start-time increment U(t_min, t_max) [s]', -1e6, 1e6),
    'velocity_variation': (
        'stationary std of the speed fluctuation along the road [m/s]',
        0.0,
        1e6,
    ),
    'variation_length': ('correlation length of the speed fluctuation [m]', 1e-6, 1e9),
    'variation_step': ('grid step of the speed profile [m]', 1e-6, 1e9),
    'min_speed': ('speeds are clipped at this floor [m/s]', 1e-9, 1e6),
    'miss_probability': ('probability that a passage is not reported [-], in [0, 1)', 0.0, 1.0),
    'false_alarm_rate': ('expected false alarms per sensor per target [-]', 0.0, 1e6),
    'false_alarms_per_sensor': ('expected false alarms per sensor per episode [-]', 0.0, 1e9),
    'stamp_noise': ('std of the Gaussian stamp noise [s]', 0.0, 1e6),
    'velocity_noise': ('std of the Gaussian speed noise [m/s]', 0.0, 1e6),
}


def _sim_specs() -> list[ParamSpec]:
    """One read-only parameter per SimConfig field (all of them, whatever the core adds)."""
    specs = []
    defaults = SimConfig()
    for f in fields(SimConfig):
        value = getattr(defaults, f.name)
        if isinstance(value, int) and not isinstance(value, bool):
            value = int(value)
        elif isinstance(value, float):
            value = float(value)
        doc, low, high = _SIM_DOCS.get(f.name, (f'simulator setting {f.name}', None, None))
        specs.append(ParamSpec(f.name, value, doc, low, high, read_only=True))
    return specs


_NODE_SPECS = [
    ParamSpec(
        'seed', 0, 'seed of the layout and of every episode [-]', 0, 2**31 - 1, read_only=True
    ),
    ParamSpec('episodes', 3, 'number of episodes to publish [-]', 1, 1000000, read_only=True),
    ParamSpec(
        'real_time_factor',
        0.0,
        'pacing: passage seconds per wall second; 1.0 = real time, 0 = as fast as '
        'delivery allows (nothing is lost either way) [-]',
        0.0,
        1e6,
        check=non_negative,
    ),
    ParamSpec(
        'episode_gap',
        10.0,
        'passage-time gap between the last detection of one episode and the first of the next [s]',
        0.0,
        1e9,
        read_only=True,
    ),
    ParamSpec('publish_clock', False, 'publish /clock with the passage time [-]', read_only=True),
    ParamSpec(
        'wait_for_subscribers',
        1,
        'before the first episode, wait until every detection topic has at least this '
        'many subscribers (association node, recorder, ...) [-]',
        0,
        1000,
        read_only=True,
    ),
    ParamSpec(
        'wait_for_truth_subscribers',
        0,
        'before the first episode, wait until /road/ground_truth has at least this many '
        'subscribers (scorer, recorder, ...) [-]',
        0,
        1000,
        read_only=True,
    ),
    ParamSpec(
        'wait_timeout',
        60.0,
        'give up waiting for subscribers after this long and fail; 0 = wait forever [s]',
        0.0,
        1e9,
        read_only=True,
    ),
    ParamSpec(
        'start_delay',
        0.0,
        'extra pause after the subscribers matched, before the first episode [s]',
        0.0,
        1e6,
        read_only=True,
    ),
    ParamSpec(
        'ack_timeout',
        60.0,
        'at each episode end, wait at most this long for every subscriber to '
        'acknowledge every message [s]',
        0.0,
        1e9,
        read_only=True,
    ),
    ParamSpec(
        'keep_running',
        False,
        'stay up after the last episode (the latched layout stays available) [-]',
        read_only=True,
    ),
]


@dataclass(frozen=True)
class SensorSimConfig:
    """Everything the node needs, from its parameters (read once at startup)."""

    sim: SimConfig
    seed: int
    episodes: int
    real_time_factor: float
    episode_gap: float
    publish_clock: bool
    wait_for_subscribers: int
    wait_for_truth_subscribers: int
    wait_timeout: float
    start_delay: float
    ack_timeout: float
    keep_running: bool

    @staticmethod
    def from_values(values: dict[str, Any]) -> SensorSimConfig:
        sim_names = {f.name for f in fields(SimConfig)}
        try:
            sim = SimConfig(**{k: v for k, v in values.items() if k in sim_names})
        except (ValueError, TypeError) as exc:
            raise ParameterError(f'invalid simulator settings: {exc}') from None
        rest = {k: v for k, v in values.items() if k not in sim_names}
        return SensorSimConfig(sim=sim, **rest)


class SensorSimNode(Node):
    """Publishes the layout, then episode after episode of simulated detections."""

    def __init__(self, **node_kwargs: Any) -> None:
        """``node_kwargs`` go to rclpy's Node (context, parameter_overrides, ...)."""
        super().__init__('sensor_sim', **node_kwargs)
        values = declare_parameters(self, _sim_specs() + _NODE_SPECS, self._on_change)
        self._config: SensorSimConfig = SensorSimConfig.from_values(values)
        self._rtf: float = self._config.real_time_factor
        cfg = self._config
        self._datasets: list[Dataset] = simulate_episodes(
            cfg.sim, cfg.seed, cfg.episodes, cfg.episode_gap
        )
        #: [ns] added to every passage time, so that the stream starts at t >= 0.
        self._origin_ns: int = conv.seconds_to_ns(stream_origin(self._datasets))
        layout = self._datasets[0].layout
        self._layout = layout
        self._stop = threading.Event()
        self._layout_pub: Publisher = self.create_publisher(
            SensorLayout, qos.LAYOUT_TOPIC, qos.LAYOUT_QOS
        )
        self._episode_pub = self._reliable(
            self.create_publisher(EpisodeInfo, qos.EPISODE_TOPIC, qos.EPISODE_QOS)
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
        self.get_logger().info(
            f'{layout.n_sensors} sensors on {layout.road_length:g} m, {cfg.episodes} episodes '
            f'of {cfg.sim.n_targets} targets, seed {cfg.seed}, real_time_factor {self._rtf:g}'
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
        return [*self._det_pubs, self._truth_pub, self._episode_pub]

    def _wait_acked(self) -> bool:
        return wait_all_acked(self._reliable_publishers(), self._config.ack_timeout)

    def _run(self) -> None:
        try:
            if not self._wait_for_subscribers():
                return
            if self._config.start_delay > 0:
                self._stop.wait(self._config.start_delay)
            self._anchor = None
            for k, dataset in enumerate(self._datasets):
                if self._interrupted() or not self._publish_episode(k, dataset):
                    return
            if not self._wait_acked() and not self._interrupted():
                self.get_logger().warning('not every message was acknowledged in time')
            if self._interrupted():
                return
            flow = total_stats(self._reliable_publishers())
            self.get_logger().info(
                f'published {self._published} detections in {len(self._datasets)} episodes '
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
