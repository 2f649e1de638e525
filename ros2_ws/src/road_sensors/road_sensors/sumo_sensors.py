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
  each passage published as SUMO produces it; no EpisodeInfo, episode_id 0 and one target
  numbering for the whole run in ground truth; ``duration`` 0 runs until stopped.

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

from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_ros.params import ParameterError, declare_parameters
from mlkm_ros.publishing import PublishTimeout, ReliablePublisher, total_stats, wait_all_acked
from mlkm_sumo import PassageStream, SumoDataset, SumoError, episodes, road
from mlkm_sumo.measurement import PASSAGE
from road_sensor_msgs.msg import Detection, EpisodeInfo, GroundTruth, SensorLayout
from road_sensors.sumo_params import SPECS, SumoSensorsConfig

#: Exit code of bad parameters and of SUMO's own errors.
EXIT_SUMO = 2
#: Smallest passage-time step between two /clock messages [ns].
CLOCK_STEP_NS = 10_000_000
#: Continuous mode logs its progress every this many simulated seconds [s].
PROGRESS_EVERY = 60.0


class SumoSensorsNode(Node):
    """Publishes the layout, then SUMO's detections episode by episode or as a stream."""

    def __init__(self, **node_kwargs: Any) -> None:
        """``node_kwargs`` go to rclpy's Node (context, parameter_overrides, ...). Raises
        ParameterError (a refused parameter) or SumoError (scenario, network, stations)."""
        super().__init__('sumo_sensors', **node_kwargs)
        values = declare_parameters(self, SPECS, self._on_change)
        cfg = self._config = SumoSensorsConfig.from_values(values)
        self._rtf: float = cfg.real_time_factor
        self._road = road(cfg.scenario, cfg.stations, cfg.seed, cfg.stations_at, cfg.cache_dir)
        layout = self._road.layout
        #: [ns] added to every SUMO time so that jittered stamps stay >= 0.
        self._origin_ns = conv.seconds_to_ns(math.ceil(6.0 * cfg.measurement.stamp_jitter))
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
        self._ids = [int(s) for s in layout.sensor_ids]
        self._positions = [float(p) for p in layout.positions]
        self._anchor: tuple[float, float] | None = None  # (SUMO time, wall time)
        self._last_clock: int | None = None
        self._error: str | None = None
        self._exit_code = 0
        self._published = 0
        self._episodes_published = 0
        ramps = self._road.ramps
        self._layout_pub.publish(
            conv.layout_to_msg(
                layout,
                self._now_ns(),
                self._road.lanes,
                [r.position for r in ramps if r.kind == 'on'],
                [r.position for r in ramps if r.kind == 'off'],
            )
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
        self._thread = threading.Thread(target=self._run, name='sumo_sensors', daemon=True)
        self._thread.start()

    # --- parameters -----------------------------------------------------------------------
    def _on_change(self, changed: dict[str, Any]) -> None:
        if 'real_time_factor' in changed:
            self._rtf = float(changed['real_time_factor'])
            self._anchor = None

    # --- publishing helpers ---------------------------------------------------------------
    def _reliable(self, publisher: Publisher) -> ReliablePublisher:
        return ReliablePublisher(publisher, self.context, self._stop)

    def _interrupted(self) -> bool:
        """A stop request or Ctrl-C (which shuts the context down under the worker thread)."""
        return self._stop.is_set() or not self.context.ok()

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _reliable_publishers(self) -> list[ReliablePublisher]:
        return [*self._det_pubs, self._truth_pub, self._episode_pub]

    def _wait_for_subscribers(self) -> bool:
        cfg = self._config
        deadline = None if cfg.wait_timeout <= 0 else time.monotonic() + cfg.wait_timeout
        announced = False
        while not self._interrupted():
            try:
                least = min(p.publisher.get_subscription_count() for p in self._det_pubs)
                truth = self._truth_pub.publisher.get_subscription_count()
            except RCLError:
                if self._interrupted():
                    return False
                raise
            if least >= cfg.wait_for_subscribers and truth >= cfg.wait_for_truth_subscribers:
                return True
            if not announced:
                self.get_logger().info(
                    f'waiting for {cfg.wait_for_subscribers} subscriber(s) on every detection '
                    f'topic and {cfg.wait_for_truth_subscribers} on ground truth'
                )
                announced = True
            if deadline is not None and time.monotonic() > deadline:
                self._fail(
                    f'no subscribers after {cfg.wait_timeout:g} s: detection topics have '
                    f'{least} (need {cfg.wait_for_subscribers}), ground truth has '
                    f'{truth} (need {cfg.wait_for_truth_subscribers})'
                )
                return False
            self._stop.wait(0.05)
        return False

    def _pace(self, stamp: float) -> None:
        """Sleep until the wall time of SUMO time ``stamp`` (real_time_factor > 0)."""
        rtf = self._rtf
        if rtf <= 0:
            return
        if self._anchor is None:
            self._anchor = (stamp, time.monotonic())
        t_sim, t_wall = self._anchor
        delay = t_wall + (stamp - t_sim) / rtf - time.monotonic()
        if delay > 0:
            self._stop.wait(delay)

    def _publish_one(
        self,
        episode: int,
        station: int,
        t_ns: int,
        lane: int,
        speed: float,
        length: float,
        target: int,
        true_speed: float,
        vehicle: str,
    ) -> bool:
        """One detection and its ground truth; False when interrupted."""
        if self._clock_pub is not None and (
            self._last_clock is None or t_ns - self._last_clock >= CLOCK_STEP_NS
        ):
            self._clock_pub.publish(Clock(clock=conv.ns_to_time(t_ns)))
            self._last_clock = t_ns
        sid = self._ids[station]
        return self._det_pubs[station].publish(
            conv.detection_to_msg(sid, t_ns, self._positions[station], speed, lane, length)
        ) and self._truth_pub.publish(
            conv.ground_truth_to_msg(episode, sid, t_ns, target, true_speed, lane, vehicle)
        )

    # --- the run --------------------------------------------------------------------------
    def _fail(self, message: str, code: int = 1) -> None:
        if self._error is None:
            self._error, self._exit_code = message, code

    def _run(self) -> None:
        try:
            if not self._wait_for_subscribers():
                return
            if self._config.start_delay > 0:
                self._stop.wait(self._config.start_delay)
            self._anchor = None
            done = self._run_episodes() if self._config.mode == 'episodes' else self._stream()
            if not done or self._interrupted():
                return
            if not wait_all_acked(self._reliable_publishers(), self._config.ack_timeout):
                if not self._interrupted():
                    self.get_logger().warning('not every message was acknowledged in time')
            flow = total_stats(self._reliable_publishers())
            self.get_logger().info(
                f'published {self._published} detections'
                + (
                    f' in {self._episodes_published} episodes'
                    if self._config.mode == 'episodes'
                    else ''
                )
                + f' (waited {flow["waited"]:g} s for subscribers: {flow["window_waits"]} '
                f'flow-control waits, {flow["retries"]} refused publishes retried)'
            )
        except SumoError as exc:
            self._fail(f'SUMO failed: {exc}', EXIT_SUMO)
        except PublishTimeout as exc:
            self._fail(str(exc))
        except Exception as exc:  # noqa: BLE001 - reported, and the process exits nonzero
            if not self._interrupted():
                self._fail(f'{type(exc).__name__}: {exc}')
        finally:
            if not self._config.keep_running or self._error:
                rclpy.try_shutdown(context=self.context)

    def _run_episodes(self) -> bool:
        cfg = self._config
        batches = episodes(
            cfg.scenario,
            cfg.vehicles,
            cfg.episodes,
            cfg.stations,
            cfg.seed,
            cfg.stations_at,
            cfg.measurement,
            cfg.cache_dir,
            cfg.step_length,
            cfg.flow,
        )
        with contextlib.closing(batches):  # an early stop closes SUMO
            for k, dataset in enumerate(batches):
                if self._interrupted() or not self._publish_episode(k, dataset):
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
        if not self._episode_pub.publish(
            conv.episode_started_msg(k, ds.n_targets, start_ns, end_ns, self._now_ns())
        ):
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
                k, station[i], t_ns[i], lane[i], speed[i], length[i], target[i],
                true_speed[i], vehicle[i],
            ):  # fmt: skip
                return False
        self._published += len(order)
        counts = np.bincount(det.sensor_index, minlength=len(self._ids))
        # No acknowledgement wait here: ENDED's counts tell the receivers how many to expect.
        ended = self._episode_pub.publish(
            conv.episode_ended_msg(
                k,
                ds.n_targets,
                start_ns,
                end_ns,
                self._now_ns(),
                {sid: int(c) for sid, c in zip(self._ids, counts)},
            )
        )
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
        cfg = self._config
        stream = PassageStream(
            cfg.scenario,
            cfg.stations,
            cfg.seed,
            cfg.duration,
            cfg.stations_at,
            cfg.measurement,
            cfg.cache_dir,
            cfg.step_length,
            cfg.flow,
        )
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
                    0, p.station, t_ns, p.lane, p.speed, p.length, target, p.true_speed,
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

    # --- lifecycle ------------------------------------------------------------------------
    @property
    def error(self) -> str | None:
        return self._error

    @property
    def exit_code(self) -> int:
        return self._exit_code

    def wait_done(self, timeout: float) -> bool:
        """Wait until the run ended (finished, failed or interrupted); False on timeout."""
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def stop(self) -> None:
        """Interrupt the publishing thread and wait for it (SUMO is closed on the way)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=10.0)

    def destroy_node(self) -> None:
        self.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    try:
        node = SumoSensorsNode()
    except (ParameterError, SumoError) as exc:
        print(f'sumo_sensors: error: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        return EXIT_SUMO
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.stop()  # first: the thread must not report an interruption as an error
        error, code = node.error, node.exit_code
        node.destroy_node()
        rclpy.try_shutdown()
    if error:
        print(f'sumo_sensors: error: {error}', file=sys.stderr)
        return code
    return 0


if __name__ == '__main__':
    sys.exit(main())
