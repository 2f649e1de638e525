"""What every road-side source node does around its detections.

``SensorSource`` is the base of ``sensor_sim``, ``sumo_sensors`` and ``log_source``: it
declares the parameters, publishes the latched layout, owns one reliable KEEP_ALL publisher
per station plus ground truth (silent for a source without it) and EpisodeInfo for an
episodic source, behind the shared back-pressure policy (``mlkm_ros.publishing``), optional
/clock, the pacing by ``real_time_factor`` (0 = as fast as delivery allows), the wait for
subscribers before the start, EpisodeInfo STARTED and ENDED with the per-station counts, the
final wait for every acknowledgement and the run's error and exit status. A subclass makes
its detections: it implements ``_publish_all`` (with ``_pace``, ``_publish_one`` and the
episode messages) and ``_summary``.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.node import Node
from rclpy.publisher import Publisher
from rosgraph_msgs.msg import Clock

from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_ros.params import ParamSpec, declare_parameters
from mlkm_ros.publishing import PublishTimeout, ReliablePublisher, total_stats, wait_all_acked
from road_sensor_msgs.msg import Detection, EpisodeInfo, GroundTruth, SensorLayout
from road_sensors.delivery import DeliveryConfig

#: Smallest passage-time step between two /clock messages [ns].
CLOCK_STEP_NS = 10_000_000


class SensorSource(Node):
    """Publishing skeleton of a simulated source; see the module docstring."""

    #: How long ``stop`` waits for the publishing thread [s].
    stop_timeout = 5.0

    def __init__(
        self,
        name: str,
        specs: list[ParamSpec],
        make_config: Callable[[dict[str, Any]], Any],
        **node_kwargs: Any,
    ) -> None:
        """Declares ``specs`` and builds the config with ``make_config`` (which may raise
        ParameterError); ``node_kwargs`` go to rclpy's Node."""
        super().__init__(name, **node_kwargs)
        values = declare_parameters(self, specs, self._on_change)
        self._config = make_config(values)
        self._rtf: float = self._config.real_time_factor
        self._anchor: tuple[float, float] | None = None  # (passage time, wall time)
        self._last_clock: int | None = None
        self._stop = threading.Event()
        self._done = threading.Event()
        self._error: str | None = None
        self._exit_code = 0
        self._published = 0

    def _open(
        self, layout: Layout, episodic: bool, layout_msg: SensorLayout, truth: bool = True
    ) -> None:
        """Create the publishers of ``layout``'s stations and publish ``layout_msg``. A
        continuous (not ``episodic``) source has no /road/episode publisher at all (receivers
        in mode auto tell the two kinds of source apart by it). A source without ground truth
        (not ``truth``: a detector log without target ids) keeps its ground-truth publisher,
        so that the waits for subscribers behave alike, but never publishes on it."""
        cfg: DeliveryConfig = self._config
        self._with_truth = truth
        self._layout_pub: Publisher = self.create_publisher(
            SensorLayout, qos.LAYOUT_TOPIC, qos.LAYOUT_QOS
        )
        self._episode_pub: ReliablePublisher | None = (
            self._reliable(self.create_publisher(EpisodeInfo, qos.EPISODE_TOPIC, qos.EPISODE_QOS))
            if episodic
            else None
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
        self._layout_pub.publish(layout_msg)

    def _start(self) -> None:
        """Start the publishing thread (after the subclass logged what it will publish)."""
        self._thread = threading.Thread(target=self._run, name=self.get_name(), daemon=True)
        self._thread.start()

    # --- what a subclass implements -------------------------------------------------------
    def _publish_all(self) -> bool:
        """Publish every detection; False when interrupted or failed (after ``_fail``)."""
        raise NotImplementedError

    def _summary(self) -> str:
        """What follows 'published N detections' in the final log line."""
        raise NotImplementedError

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
        extra = [] if self._episode_pub is None else [self._episode_pub]
        return [*self._det_pubs, self._truth_pub, *extra]

    def _subscription_counts(self) -> tuple[int, int] | None:
        """(fewest subscribers of a detection topic, their sum, ground-truth subscribers);
        None when interrupted (the context may vanish between two counts)."""
        try:
            counts = [p.publisher.get_subscription_count() for p in self._det_pubs]
            truth = self._truth_pub.publisher.get_subscription_count()
        except RCLError:
            if self._interrupted():
                return None
            raise
        return min(counts), sum(counts), truth

    def _wait_for_subscribers(self) -> bool:
        cfg: DeliveryConfig = self._config
        deadline = None if cfg.wait_timeout <= 0 else time.monotonic() + cfg.wait_timeout
        announced = False
        while not self._interrupted():
            counts = self._subscription_counts()
            if counts is None:
                return False
            least, total, truth = counts
            if (
                least >= cfg.wait_for_subscribers
                and total >= cfg.wait_for_subscriptions
                and truth >= cfg.wait_for_truth_subscribers
            ):
                return True
            if not announced:
                self.get_logger().info(
                    f'waiting for {cfg.wait_for_subscribers} subscriber(s) on every detection '
                    f'topic ({cfg.wait_for_subscriptions} on them all) and '
                    f'{cfg.wait_for_truth_subscribers} on ground truth'
                )
                announced = True
            if deadline is not None and time.monotonic() > deadline:
                self._fail(
                    f'no subscribers after {cfg.wait_timeout:g} s: detection topics have '
                    f'{least} (need {cfg.wait_for_subscribers}), {total} together (need '
                    f'{cfg.wait_for_subscriptions}), ground truth has {truth} (need '
                    f'{cfg.wait_for_truth_subscribers})'
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

    def _publish_one(
        self,
        episode: int,
        station: int,
        t_ns: int,
        speed: float,
        target: int,
        true_speed: float,
        lane: int = conv.LANE_UNKNOWN,
        length: float = float('nan'),
        vehicle: str = '',
    ) -> bool:
        """One detection of station index ``station`` and its ground truth (after /clock
        when due; no ground truth from a source without it); False when interrupted."""
        if self._clock_pub is not None and (
            self._last_clock is None or t_ns - self._last_clock >= CLOCK_STEP_NS
        ):
            self._clock_pub.publish(Clock(clock=conv.ns_to_time(max(t_ns, 0))))
            self._last_clock = t_ns
        sid = self._ids[station]
        if not self._det_pubs[station].publish(
            conv.detection_to_msg(sid, t_ns, self._positions[station], speed, lane, length)
        ):
            return False
        return not self._with_truth or self._truth_pub.publish(
            conv.ground_truth_to_msg(episode, sid, t_ns, target, true_speed, lane, vehicle)
        )

    def _episode_started(self, k: int, n_targets: int, start_ns: int, end_ns: int) -> bool:
        """EpisodeInfo STARTED of episode ``k``; False when interrupted."""
        return self._episode_pub.publish(
            conv.episode_started_msg(k, n_targets, start_ns, end_ns, self._now_ns())
        )

    def _episode_ended(
        self,
        k: int,
        n_targets: int,
        start_ns: int,
        end_ns: int,
        sensor_index: Sequence[int] | np.ndarray,
    ) -> bool:
        """EpisodeInfo ENDED of episode ``k`` with the count of every station in
        ``sensor_index`` (the station indices of its detections); False when interrupted.

        No acknowledgement wait here (Fast DDS acknowledges on its heartbeat period, ~3 s):
        ENDED may overtake detections on other topics; its counts tell the receivers how many
        to expect. The run ends with a wait for every acknowledgement."""
        counts = np.bincount(sensor_index, minlength=len(self._ids))
        return self._episode_pub.publish(
            conv.episode_ended_msg(
                k,
                n_targets,
                start_ns,
                end_ns,
                self._now_ns(),
                {sid: int(c) for sid, c in zip(self._ids, counts)},
            )
        )

    # --- the run --------------------------------------------------------------------------
    def _fail(self, message: str, code: int = 1) -> None:
        """Record the run's first error and the exit code that goes with it."""
        if self._error is None:
            self._error, self._exit_code = message, code

    def _run(self) -> None:
        cfg: DeliveryConfig = self._config
        try:
            if not self._wait_for_subscribers():
                return
            if cfg.start_delay > 0:
                self._stop.wait(cfg.start_delay)
            self._anchor = None
            if not self._publish_all() or self._interrupted():
                return
            if not wait_all_acked(self._reliable_publishers(), cfg.ack_timeout):
                if not self._interrupted():
                    self.get_logger().warning('not every message was acknowledged in time')
            if self._interrupted():
                return
            flow = total_stats(self._reliable_publishers())
            self.get_logger().info(
                f'published {self._published} detections{self._summary()} '
                f'(waited {flow["waited"]:g} s for subscribers: {flow["window_waits"]} '
                f'flow-control waits, {flow["retries"]} refused publishes retried)'
            )
        except PublishTimeout as exc:
            self._fail(str(exc))
        except Exception as exc:  # noqa: BLE001 - reported, and the process exits nonzero
            if not self._interrupted():
                self._fail(f'{type(exc).__name__}: {exc}')
        finally:
            self._done.set()
            if not cfg.keep_running or self._error:
                rclpy.try_shutdown(context=self.context)

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

    def finish(self, name: str, prefix: str = '') -> int:
        """After the spin: stop the publishing thread (first: it must not report the
        interruption as an error), print the run's error as ``<name>: <prefix><error>`` and
        return the exit status."""
        self.stop()
        if self._error:
            print(f'{name}: {prefix}{self._error}', file=sys.stderr)
            return self._exit_code
        return 0

    def stop(self) -> None:
        """Interrupt the publishing thread and wait for it."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=self.stop_timeout)

    def destroy_node(self) -> None:
        self.stop()
        super().destroy_node()
