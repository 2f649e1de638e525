"""``mlkm_assoc association_node``: incremental data association of live detections.

A thin adapter: parameters -> :class:`AssociationConfig`; messages -> plain values
(:mod:`mlkm_ros.conversions`); the ROS-free :class:`~mlkm_assoc.assembly.Assembler`
buffers detections per episode and segment and decides completion; a solver thread runs the
core associator (:mod:`mlkm_assoc.solver`) on each completed segment and publishes the
updated tracks, so the executor thread only ever appends to lists (fast ingest).
"""

from __future__ import annotations

import re
import sys
import threading
import time
from dataclasses import replace
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.subscription import Subscription

from mlkm_assoc.assembly import Assembler, AssociationConfig, Job
from mlkm_assoc.association_diagnostics import AssociationDiagnostics
from mlkm_assoc.association_markers import RoadMarkers
from mlkm_assoc.association_params import (
    BOUND_NAMES,
    MARKER_PARAMS,
    NODE_PARAMS,
    SPECS,
    STREAM_PARAMS,
    stream_associator,
)
from mlkm_assoc.encoding import Update, encode
from mlkm_assoc.modes import ModeSwitch
from mlkm_assoc.shard_link import SHARD_PARAMS, ShardLink, source_topic
from mlkm_assoc.solver import SolverProcess
from mlkm_assoc.stream_worker import prestart
from mlkm_core.associators.base import AssociatorConfig
from mlkm_core.network_assoc.stations import (
    NetworkStations,
    network_method_problem,
    network_stations,
)
from mlkm_ros import conversions as conv
from mlkm_ros import lifecycle, qos
from mlkm_ros.endpoints import PublisherCheck, no_events
from mlkm_ros.network_conversions import is_network_msg, msg_to_network
from mlkm_ros.params import ParameterError, declare_parameters
from mlkm_ros.publishing import tracks_publisher
from road_sensor_msgs.msg import Detection, EpisodeInfo, SensorLayout

DETECTION_TYPE = 'road_sensor_msgs/msg/Detection'
NS_PER_S = conv.NS_PER_S


def read_layout(msg: SensorLayout) -> tuple:
    """(layout, lane counts, entries, exits) of a layout message; ValueError with the reason
    when it is invalid. A road network becomes the :class:`NetworkStations` of its stations,
    its entries and exits are the network's (the associator's config has none)."""
    if is_network_msg(msg):
        net = msg_to_network(msg)
        lanes = tuple(int(n) for n in net.station_lanes) if net.station_lanes.any() else None
        return network_stations(net), lanes, (), ()
    layout = conv.layout_from_msg(msg)
    entries, exits = conv.layout_ramps(msg)
    AssociatorConfig(entries=entries, exits=exits)  # finite positions
    return layout, conv.lane_counts_from_msg(msg), entries, exits


class AssociationNode(Node):
    """Subscribes to the layout, episodes and every sensor; publishes tracks and diagnostics."""

    def __init__(self, node_name: str = 'association_node', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        values = declare_parameters(self, SPECS, self._on_change)
        self.add_on_set_parameters_callback(self._check_bounds)
        self._diag_period: float = values.pop('diagnostics_period')
        self._stats = AssociationDiagnostics(
            values.pop('diagnostics_window'), values.pop('warn_rejected_fraction')
        )
        mode, lag, stream_method = (values.pop(name) for name in STREAM_PARAMS)
        max_uncommitted: int = values.pop('max_uncommitted')
        quiet_flush: float = values.pop('quiet_flush')
        wait_for_track_subscribers: int = values.pop('wait_for_track_subscribers')
        markers = [values.pop(name) for name in MARKER_PARAMS]
        self._source_ns: str = values.pop('source_namespace')
        shard = [values.pop(name) for name in SHARD_PARAMS]
        # the values given on the command line or in a params file (rclpy keeps them as the
        # node's parameter overrides)
        given = set(getattr(self, '_parameter_overrides', {}))
        stream_method = stream_associator(values['method'], stream_method, given)
        try:
            self._config: AssociationConfig = AssociationConfig(**values)
            self._config.bounds()
        except ValueError as exc:
            raise ParameterError(f'speed, stamp and length bounds refused: {exc}') from None
        self._assembler: Assembler = Assembler(self._config, self._submit, self._on_reject)
        self._solver: SolverProcess = SolverProcess(encode)
        self._diagnostics_due: bool = False
        self._det_subs: dict[str, Subscription] = {}
        self._publisher_check = PublisherCheck(self, DETECTION_TYPE, qos.DETECTIONS_QOS)
        self._prefix_re = re.compile(
            '^'
            + re.escape(source_topic(self, self._source_ns, qos.DETECTIONS_PREFIX))
            + r'/([^/]+)/detections$'
        )
        self._tracks_pub = tracks_publisher(self, wait_for_track_subscribers, self._on_tracks_held)
        self._diag_pub = self.create_publisher(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, qos.DIAGNOSTICS_QOS
        )
        self._layout_sub = self.create_subscription(
            SensorLayout,
            source_topic(self, self._source_ns, qos.LAYOUT_TOPIC),
            self._on_layout,
            qos.LAYOUT_QOS,
        )
        self._episode_sub = self.create_subscription(
            EpisodeInfo,
            source_topic(self, self._source_ns, qos.EPISODE_TOPIC),
            self._on_episode,
            qos.EPISODE_QOS,
        )
        self._shards: ShardLink | None = None
        if shard[1] > 1:  # (index, count, margin, horizon)
            if mode != 'stream':
                raise ParameterError('shards (shard_count > 1) run in mode stream only')
            if shard[0] >= shard[1]:
                raise ParameterError(f'shard_index {shard[0]} is not below shard_count {shard[1]}')
            self._shards = ShardLink(self, *shard)
        self._tick_timer = self.create_timer(0.25, self._on_tick)
        self._diag_timer = self.create_timer(self._diag_period, self.publish_diagnostics)
        self._worker = threading.Thread(target=self._work, name='publisher', daemon=True)
        self._worker.start()
        self._markers = RoadMarkers(self, *markers)
        self._modes = ModeSwitch(
            self,
            self._tracks_pub,
            mode,
            lag,
            stream_method,
            max_uncommitted=max_uncommitted,
            quiet_flush=quiet_flush,
            on_publish=self._markers.tracks,
            publish_handoff=None if self._shards is None else self._shards.publish,
        )
        self.get_logger().info(
            f'method {self._config.method}, segment_size {self._config.segment_size}, '
            f'stream mode method {stream_method}; waiting for the sensor layout'
        )

    # --- parameters -----------------------------------------------------------------------
    def _check_bounds(self, params: list[Parameter]) -> SetParametersResult:
        """Refuse a change that would leave min above max (the ranges alone cannot)."""
        new = {p.name: p.value for p in params if p.name in BOUND_NAMES}
        if not new:
            return SetParametersResult(successful=True)
        try:
            AssociationConfig(**(self._config.__dict__ | new)).bounds()
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _on_change(self, changed: dict[str, Any]) -> None:
        if 'diagnostics_window' in changed:
            self._stats.window = changed['diagnostics_window']
        if 'warn_rejected_fraction' in changed:
            self._stats.warn_fraction = changed['warn_rejected_fraction']
        if 'markers' in changed:
            self._markers.enabled = changed['markers']
        keep = {k: v for k, v in changed.items() if k not in NODE_PARAMS}
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
            layout, lane_counts, entries, exits = read_layout(msg)
            role = None
            if self._shards is not None:
                if isinstance(layout, NetworkStations):
                    raise ValueError('shards split a road; a road network is taken whole')
                layout, lane_counts, role = self._shards.region(layout, lane_counts)
            wanted = {
                source_topic(self, self._source_ns, qos.detections_topic(n)) for n in layout.names
            }
        except Exception as exc:  # noqa: BLE001 - invalid values or sensor names
            self._assembler.rejected['invalid_layout'] += 1
            self.get_logger().error(
                f'sensor layout refused, keeping the previous one: {exc}',
                throttle_duration_sec=2.0,
            )
            return
        if (entries, exits) != (self._config.entries, self._config.exits):
            # the episodes that begin from now on associate on the layout's open road
            self._config = replace(self._config, entries=entries, exits=exits)
            self._assembler.config = self._config
        self._markers.layout(layout)
        runs = self._assembler.runs
        published_ns = conv.time_to_ns(msg.header.stamp)
        if not self._assembler.set_layout(layout, time.monotonic(), published_ns, lane_counts):
            return
        self._modes.layout(msg, layout, lane_counts, role)
        if self._shards is not None:
            self._shards.connect(self._modes.stream.handoff)
        if self._assembler.runs != runs:
            self.get_logger().info('a new layout: a new run of the source begins')
        for topic in list(self._det_subs):
            if topic not in wanted:
                self.destroy_subscription(self._det_subs.pop(topic))
        for topic in sorted(wanted):
            self._subscribe(topic)
        if isinstance(layout, NetworkStations):
            net = layout.network
            where = f'a road network of {len(net.links)} links'
            problem = network_method_problem(self._config.method)
            if problem and self._modes.mode != 'stream':
                self.get_logger().warning(f'{problem}: set the method parameter')
        else:
            where = f'{layout.road_length:g} m'
        self.get_logger().info(
            f'layout: {layout.n_sensors} sensors on {where}; '
            f'subscribed to {len(wanted)} detection topics'
        )

    def _subscribe(self, topic: str) -> None:
        if topic not in self._det_subs:
            self._det_subs[topic] = self.create_subscription(
                Detection,
                topic,
                self._on_detection,
                qos.DETECTIONS_QOS,
                event_callbacks=no_events(),
            )

    def _on_detection(self, msg: Detection) -> None:
        stamp = msg.header.stamp
        stamp_ns = stamp.sec * NS_PER_S + stamp.nanosec
        if self._markers.enabled:
            self._markers.detection(
                msg.sensor_id,
                stamp_ns,
                msg.position,
                msg.velocity,
                msg.lane,
                self._assembler.bounds,
            )
        if self._modes.take_detection(msg):
            return
        self._assembler.add_detection(
            msg.sensor_id,
            stamp_ns,
            msg.position,
            msg.velocity,
            time.monotonic(),
            msg.lane,
            conv.detection_length(msg),
        )

    def _on_episode(self, msg: EpisodeInfo) -> None:
        self._modes.episode_info()
        try:
            info = conv.episode_from_msg(msg)
        except ValueError as exc:
            self._assembler.rejected['invalid_episode'] += 1
            self.get_logger().error(
                f'EpisodeInfo of episode {msg.episode_id} refused: {exc}',
                throttle_duration_sec=2.0,
            )
            return
        runs = self._assembler.runs
        self._assembler.add_episode(
            info.episode_id,
            info.num_targets,
            info.start_ns,
            info.end_ns,
            info.counts,
            time.monotonic(),
            info.published_ns,
        )
        if self._assembler.runs != runs:
            self.get_logger().info(
                f'EpisodeInfo of episode {info.episode_id} from a restarted source: a new run '
                'begins'
            )

    def _on_tracks_held(self, held: int, subscribers: int) -> None:
        self.get_logger().info(
            f'{held} TrackArray(s) held until {qos.TRACKS_TOPIC} has '
            f'{self._tracks_pub.least} subscriber(s) (wait_for_track_subscribers), '
            f'{subscribers} now',
            throttle_duration_sec=5.0,
        )

    def _on_tick(self) -> None:
        self._tracks_pub.poll()
        self._assembler.tick(time.monotonic())
        self._modes.tick(time.monotonic())
        self._publisher_check.check(list(self._det_subs))
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
        self._markers.tracks(update.data)
        self._stats.published(update, time.monotonic() - update.completed_at)
        if update.error:
            self.get_logger().error(update.error)
        if update.final:
            self.get_logger().info(
                f'episode {update.episode_id}: final tracks, {update.detections} detections '
                f'in {update.tracks} tracks, {update.unassigned} unassigned, '
                f'{update.missing} missing'
            )
            self._diagnostics_due = True  # published from the executor thread

    # --- diagnostics ----------------------------------------------------------------------
    def diagnostics(self) -> dict[str, object]:
        values = self._stats.values(
            self._config, self._assembler, self._publisher_check.incompatible
        )
        self._modes.diagnostics(values)
        if self._shards is not None:
            self._shards.diagnostics(values)
        values['tracks_held'] = self._tracks_pub.held
        # how long the track subscribers made the node wait [s], refused publishes retried
        values['tracks_publish_waited'] = round(self._tracks_pub.publisher.waited, 3)
        values['tracks_publish_retries'] = self._tracks_pub.publisher.retries
        return values

    def diagnostics_level(self, values: dict[str, object], now: float) -> tuple[int, str]:
        """(level, reason) of ``values`` (see AssociationDiagnostics.level)."""
        return self._stats.level(values, now)

    def publish_diagnostics(self) -> None:
        values = self.diagnostics()
        level, reason = self.diagnostics_level(values, time.monotonic())
        message = (
            f'{values["received"]} detections received, {values["rejected"]} rejected, '
            f'{values["segments_done"]} segments, {values["episodes_final"]} episodes'
        )
        if reason:
            message = f'{reason}; {message}'
        self._diag_pub.publish(
            conv.diagnostics_to_msg(
                name=self.get_fully_qualified_name(),
                hardware_id='mlkm_assoc',
                level=level,
                message=message,
                values=values,
                stamp_ns=self.get_clock().now().nanoseconds,
            )
        )

    def destroy_node(self) -> None:
        self._modes.close()
        self._solver.close()
        if self._worker.is_alive():
            self._worker.join(timeout=10.0)
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    # stream mode's processes are forked while no ROS thread runs (mlkm_assoc.stream_worker);
    # a Ctrl-C drops the solves in hand
    return lifecycle.run_node(
        'association_node', AssociationNode, args, before_init=prestart, drop_helpers=True
    )


if __name__ == '__main__':
    sys.exit(main())
