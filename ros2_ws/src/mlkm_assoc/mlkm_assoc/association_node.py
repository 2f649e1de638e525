"""``mlkm_assoc association_node``: incremental data association of live detections.

A thin adapter: parameters -> :class:`AssociationConfig`; messages -> plain values
(:mod:`mlkm_ros.conversions`); the ROS-free :class:`~mlkm_assoc.assembly.Assembler`
buffers detections per episode and segment and decides completion; a solver thread runs the
core associator (:mod:`mlkm_assoc.solver`) on each completed segment and publishes the
updated tracks, so the executor thread only ever appends to lists (fast ingest).
"""

from __future__ import annotations

import re
import statistics
import sys
import threading
import time
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.subscription import Subscription

from mlkm_assoc.assembly import REJECT_REASONS, Assembler, AssociationConfig, Job
from mlkm_assoc.solver import SolverProcess, Update
from mlkm_core.associators.base import available_methods
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_ros.params import ParameterError, ParamSpec, declare_parameters, positive
from road_sensor_msgs.msg import Detection, EpisodeInfo, SensorLayout, TrackArray

DETECTION_TYPE = 'road_sensor_msgs/msg/Detection'
NS_PER_S = conv.NS_PER_S


def _check_method(value: str) -> str | None:
    methods = available_methods()
    if value in methods:
        return None
    return f'unknown method {value!r}; choose one of {", ".join(methods)}'


SPECS = [
    ParamSpec(
        'method',
        'mlkm',
        'associator from the core, any of mlkm_core available_methods() (applies from '
        'the next episode) [-]',
        check=_check_method,
    ),
    ParamSpec(
        'segment_size',
        5,
        'K: sensors per road segment; one association update per completed segment '
        '(applies from the next episode) [-]',
        1,
        100000,
    ),
    ParamSpec(
        'seed',
        0,
        'random state of the associator (applies from the next episode) [-]',
        0,
        2**31 - 1,
    ),
    ParamSpec(
        'completion_timeout',
        5.0,
        'after an episode ended, associate what is there once nothing arrived for this '
        'long; also how long a detection waits for its episode [s]',
        1e-3,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'diagnostics_period', 1.0, 'period of /diagnostics [s]', 0.01, 3600.0, read_only=True
    ),
]


class AssociationNode(Node):
    """Subscribes to the layout, episodes and every sensor; publishes tracks and diagnostics."""

    def __init__(self, node_name: str = 'association_node', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        values = declare_parameters(self, SPECS, self._on_change)
        self._diag_period: float = values.pop('diagnostics_period')
        self._config: AssociationConfig = AssociationConfig(**values)
        self._assembler: Assembler = Assembler(self._config, self._submit, self._on_reject)
        self._solver: SolverProcess = SolverProcess()
        self._solve_times: list[float] = []
        self._latencies: list[float] = []  # segment complete -> its tracks published [s]
        self._waits: list[float] = []  # of which waiting for the solver (earlier segments)
        self._overheads: list[float] = []  # of which neither waiting nor solving [s]
        self._solver_errors: int = 0
        self._tracks_published: int = 0
        self._finals_published: int = 0
        self._diagnostics_due: bool = False
        self._det_subs: dict[str, Subscription] = {}
        self._prefix_re = re.compile(
            '^'
            + re.escape(self.resolve_topic_name(qos.DETECTIONS_PREFIX))
            + r'/([^/]+)/detections$'
        )
        self._tracks_pub = self.create_publisher(TrackArray, qos.TRACKS_TOPIC, qos.TRACKS_QOS)
        self._diag_pub = self.create_publisher(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, qos.DIAGNOSTICS_QOS
        )
        self._layout_sub = self.create_subscription(
            SensorLayout, qos.LAYOUT_TOPIC, self._on_layout, qos.LAYOUT_QOS
        )
        self._episode_sub = self.create_subscription(
            EpisodeInfo, qos.EPISODE_TOPIC, self._on_episode, qos.EPISODE_QOS
        )
        self._tick_timer = self.create_timer(0.25, self._on_tick)
        self._diag_timer = self.create_timer(self._diag_period, self.publish_diagnostics)
        self._worker = threading.Thread(target=self._work, name='publisher', daemon=True)
        self._worker.start()
        self.get_logger().info(
            f'method {self._config.method}, segment_size {self._config.segment_size}; '
            'waiting for the sensor layout'
        )

    # --- parameters -----------------------------------------------------------------------
    def _on_change(self, changed: dict[str, Any]) -> None:
        keep = {k: v for k, v in changed.items() if k != 'diagnostics_period'}
        if keep:
            cfg = self._config.__dict__ | keep
            self._config = AssociationConfig(**cfg)
            self._assembler.config = self._config
            self.get_logger().info(f'parameters changed: {keep}')

    @property
    def config(self) -> AssociationConfig:
        return self._config

    @property
    def assembler(self) -> Assembler:
        return self._assembler

    # --- inputs ---------------------------------------------------------------------------
    def _on_layout(self, msg: SensorLayout) -> None:
        try:
            layout = conv.layout_from_msg(msg)
            wanted = {self.resolve_topic_name(qos.detections_topic(n)) for n in layout.names}
        except Exception as exc:  # noqa: BLE001 - invalid values or sensor names
            self._assembler.rejected['invalid_layout'] += 1
            self.get_logger().error(f'sensor layout refused: {exc}')
            return
        if not self._assembler.set_layout(layout, time.monotonic()):
            return
        for topic in list(self._det_subs):
            if topic not in wanted:
                self.destroy_subscription(self._det_subs.pop(topic))
        for topic in sorted(wanted):
            self._subscribe(topic)
        self.get_logger().info(
            f'layout: {layout.n_sensors} sensors on {layout.road_length:g} m; '
            f'subscribed to {len(wanted)} detection topics'
        )

    def _subscribe(self, topic: str) -> None:
        if topic not in self._det_subs:
            self._det_subs[topic] = self.create_subscription(
                Detection, topic, self._on_detection, qos.DETECTIONS_QOS
            )

    def _on_detection(self, msg: Detection) -> None:
        stamp = msg.header.stamp
        self._assembler.add_detection(
            msg.sensor_id,
            stamp.sec * NS_PER_S + stamp.nanosec,
            msg.position,
            msg.velocity,
            time.monotonic(),
        )

    def _on_episode(self, msg: EpisodeInfo) -> None:
        counts = None
        if msg.status == EpisodeInfo.STATUS_ENDED:
            try:
                counts = conv.episode_counts(msg)
            except ValueError as exc:
                self.get_logger().error(f'episode {msg.episode_id} ENDED refused: {exc}')
                return
        self._assembler.add_episode(
            msg.episode_id,
            msg.num_targets,
            conv.time_to_ns(msg.start),
            conv.time_to_ns(msg.end),
            counts,
            time.monotonic(),
        )

    def _on_tick(self) -> None:
        self._assembler.tick(time.monotonic())
        if self._diagnostics_due:
            self._diagnostics_due = False
            self.publish_diagnostics()
        if self._assembler.layout is None:
            # Before the layout: subscribe to sensor topics that already exist, so that early
            # detections are held rather than lost.
            for name, types in self.get_topic_names_and_types():
                if DETECTION_TYPE in types and self._prefix_re.match(name):
                    self._subscribe(name)

    def _on_reject(self, reason: str, detail: str) -> None:
        self.get_logger().warning(
            f'detection rejected ({reason}): {detail}; rejected so far: '
            f'{dict(self._assembler.rejected)}',
            throttle_duration_sec=2.0,
        )

    # --- solving (solver process) and publishing (worker thread) ---------------------------
    def _submit(self, job: Job) -> None:
        self._solver.submit(job)

    def _work(self) -> None:
        while True:
            result = self._solver.get()
            if result is None:
                return
            try:
                self._publish(result)
            except Exception as exc:  # noqa: BLE001 - shutting down, or a broken context
                if rclpy.ok(context=self.context):
                    self.get_logger().error(f'publishing tracks failed: {exc}')

    def _publish(self, update: Update) -> None:
        self._tracks_pub.publish(update.data)
        latency = time.monotonic() - update.completed_at
        self._tracks_published += 1
        if update.error:
            self._solver_errors += 1
            self.get_logger().error(update.error)
        if not update.final:
            self._solve_times.append(update.solve_time)
            if not update.forced:
                self._latencies.append(latency)
                wait = update.started_at - update.completed_at
                self._waits.append(wait)
                self._overheads.append(latency - wait - update.solve_time)
        else:
            self._finals_published += 1
            self.get_logger().info(
                f'episode {update.episode_id}: final tracks, {update.detections} detections '
                f'in {update.tracks} tracks, {update.unassigned} unassigned'
            )
            self._diagnostics_due = True  # published from the executor thread

    # --- diagnostics ----------------------------------------------------------------------
    def diagnostics(self) -> dict[str, object]:
        a = self._assembler
        values: dict[str, object] = {
            'method': self._config.method,
            'segment_size': self._config.segment_size,
            'sensors': 0 if a.layout is None else a.layout.n_sensors,
            'received': a.received,
            'accepted': a.accepted,
            'rejected': sum(a.rejected.values()),
        }
        for reason in (*REJECT_REASONS, 'invalid_layout'):
            values[f'rejected.{reason}'] = a.rejected.get(reason, 0)
        for reason, count in sorted(a.handled.items()):
            values[f'handled.{reason}'] = count
        values.update(a.buffer_sizes())
        values['segments_done'] = a.segments_done
        values['episodes_final'] = a.episodes_final
        values['track_updates_published'] = self._tracks_published
        values['episodes_published'] = self._finals_published
        values['solver_errors'] = self._solver_errors
        solve, lat = list(self._solve_times), list(self._latencies)
        values['solve_time_last'] = f'{solve[-1]:.6f}' if solve else ''
        values['solve_time_mean'] = f'{statistics.fmean(solve):.6f}' if solve else ''
        values['solve_time_max'] = f'{max(solve):.6f}' if solve else ''
        values['latency_p50'] = f'{_quantile(lat, 0.5):.6f}' if lat else ''
        values['latency_p95'] = f'{_quantile(lat, 0.95):.6f}' if lat else ''
        values['latency_count'] = len(lat)
        waits = list(self._waits)
        values['queue_wait_p50'] = f'{_quantile(waits, 0.5):.6f}' if waits else ''
        values['queue_wait_p95'] = f'{_quantile(waits, 0.95):.6f}' if waits else ''
        over = list(self._overheads)
        values['overhead_p50'] = f'{_quantile(over, 0.5):.6f}' if over else ''
        values['overhead_p95'] = f'{_quantile(over, 0.95):.6f}' if over else ''
        values['first_receive'] = '' if a.first_rx is None else f'{a.first_rx:.6f}'
        values['last_receive'] = '' if a.last_rx is None else f'{a.last_rx:.6f}'
        if a.first_rx is not None and a.last_rx is not None and a.last_rx > a.first_rx:
            values['ingest_rate'] = f'{(a.received - 1) / (a.last_rx - a.first_rx):.1f}'
        else:
            values['ingest_rate'] = ''
        return values

    def publish_diagnostics(self) -> None:
        values = self.diagnostics()
        rejected = int(values['rejected'])
        level = DiagnosticStatus.WARN if rejected or self._solver_errors else DiagnosticStatus.OK
        message = (
            f'{values["received"]} detections received, {rejected} rejected, '
            f'{values["segments_done"]} segments, {values["episodes_final"]} episodes'
        )
        self._diag_pub.publish(
            conv.diagnostics_to_msg(
                name=self.get_fully_qualified_name(),
                hardware_id='mlkm_assoc',
                level=level[0],
                message=message,
                values=values,
                stamp_ns=self.get_clock().now().nanoseconds,
            )
        )

    def destroy_node(self) -> None:
        self._solver.close()
        if self._worker.is_alive():
            self._worker.join(timeout=10.0)
        super().destroy_node()


def _quantile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    pos = q * (len(ordered) - 1)
    lo = int(pos)
    hi = min(lo + 1, len(ordered) - 1)
    return ordered[lo] + (ordered[hi] - ordered[lo]) * (pos - lo)


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    try:
        node = AssociationNode()
    except ParameterError as exc:
        print(f'association_node: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
