"""Which mode the association node works in: episodes (the paper's closed world) or stream.

``mode`` parameter: ``episodes`` or ``stream`` fixes it; ``auto`` (the default) follows the
source. A source with episodes publishes /road/episode; a continuous source has no such
publisher. So ``auto`` is decided at the first detection: episodes when /road/episode has a
publisher (or an EpisodeInfo arrived), stream otherwise. It is checked again every tick: an
episode publisher appearing (or an EpisodeInfo) switches to episodes at once, after the
stream was flushed (its tracks become FINAL); the publisher gone and every episode finished
switches back to stream. Detections that arrive in ``auto`` before any layout, while no
episode publisher is known, are held here (up to ``max_buffered``) and decide nothing: the
mode is decided once the layout is known or an episode publisher appears (at the next
detection or tick), and they go to that mode in arrival order.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from rclpy.publisher import Publisher

from mlkm_assoc.stream_ingest import REJECT_REASONS as STREAM_REASONS
from mlkm_assoc.stream_mode import StreamMode, StreamSettings
from mlkm_assoc.stream_worker import discard_prestarted
from mlkm_core.network_assoc.stations import NetworkStations
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import Detection, SensorLayout

MODES = ('auto', 'episodes', 'stream')
#: Period of the clock ticks stream mode's reorder buffer runs on while nothing arrives [s].
CLOCK_PERIOD = 0.02
EPISODES, STREAM = 'episodes', 'stream'


class ModeSwitch:
    """Owns stream mode (created when first needed) and tells the node where input goes."""

    def __init__(
        self,
        node: Node,
        publisher: Publisher,
        mode: str,
        lag: float,
        method: str,
        max_uncommitted: int = 0,
        quiet_flush: float = 0.0,
        on_publish: Callable[[bytes], None] | None = None,
        publish_handoff: Callable[[bytes], None] | None = None,
    ) -> None:
        self._node = node
        self._publish_handoff = publish_handoff  # a shard's TrackHandoff publisher
        self._publisher = publisher
        self._on_publish = on_publish  # also given every TrackArray published
        self.setting = mode
        self._lag = lag
        self._method = method
        self._max_uncommitted = max_uncommitted
        self._quiet_flush = quiet_flush
        self._episode_topic = node.resolve_topic_name(qos.EPISODE_TOPIC)
        self.mode: str | None = None if mode == 'auto' else mode
        self._layout: tuple | None = None
        self.stream: StreamMode | None = None
        self.switches = 0
        # auto, before any layout: (sensor id, stamp ns, position, velocity, lane, length,
        # arrival time) of the detections held until the layout decides the mode
        self._early: list[tuple[int, int, float, float, int, float, float]] = []
        self.early_held = 0  # detections held so far
        self.early_refused = 0  # detections refused because the hold was full
        if self.mode == STREAM:
            # the tracker process starts now; the node subscribes at once, and detections
            # queue for the process until it is ready (mlkm_assoc.stream_worker)
            self._start_stream()
        elif self.mode == EPISODES:
            discard_prestarted()

    # --- inputs from the node -------------------------------------------------------------
    def layout(self, msg: SensorLayout, layout, lane_counts, shard=None) -> None:
        """A new layout (already validated). The entries and exits of a road network are in
        its stations' layout (``NetworkStations``), not positions along one road. ``shard``:
        ``layout`` is this shard's region of the road (a ``ShardRole``)."""
        network = isinstance(layout, NetworkStations)
        entries, exits = ((), ()) if network else conv.layout_ramps(msg)
        if shard is not None:
            lo, hi = layout.positions[0], layout.positions[-1]
            entries = tuple(e for e in entries if lo <= e <= hi)
            exits = tuple(e for e in exits if lo <= e <= hi)
        self._layout = (layout, lane_counts, entries, exits, shard)
        if self.stream is not None:
            self.stream.set_layout(*self._layout)

    def episode_info(self) -> None:
        """An EpisodeInfo arrived: the source has episodes."""
        if self.setting == 'auto' and self.mode != EPISODES:
            self._switch(EPISODES, 'an EpisodeInfo arrived')

    def take_detection(self, msg: Detection) -> bool:
        """True when stream mode took the detection (or it is held until the mode is
        decided); False: episodes mode's."""
        stamp = msg.header.stamp
        raw = (
            msg.sensor_id,
            stamp.sec * conv.NS_PER_S + stamp.nanosec,
            msg.position,
            msg.velocity,
            msg.lane,
            conv.detection_length(msg),
            time.monotonic(),
        )
        if self.mode is None:
            self._decide()
            if self.mode is None:
                self._hold(raw)
                return True
        if self.mode != STREAM:
            return False
        self.stream.ingest.bounds = self._node.assembler.bounds  # live parameter changes
        self.stream.add(*raw)
        return True

    def _hold(self, raw: tuple) -> None:
        """A detection before any layout in ``auto`` without an episode publisher: the mode
        is not known yet (the source's /road/episode publisher may not be discovered yet),
        so it waits."""
        if len(self._early) >= self._node.config.max_buffered:
            self.early_refused += 1
            self._node._on_reject(
                'buffer_full',
                f'sensor {raw[0]}, stamp {raw[1]} ns: more than max_buffered detections '
                'before the layout',
            )
            return
        self._early.append(raw)
        self.early_held += 1

    def _release_early(self) -> None:
        """The mode is decided: the held detections go to it, in arrival order."""
        early, self._early = self._early, []
        for sensor_id, stamp_ns, position, velocity, lane, length, t_rx in early:
            if self.mode == STREAM:
                self.stream.ingest.bounds = self._node.assembler.bounds
                self.stream.add(sensor_id, stamp_ns, position, velocity, lane, length, t_rx)
            else:
                self._node.assembler.add_detection(
                    sensor_id, stamp_ns, position, velocity, t_rx, lane, length
                )

    def tick(self, now: float) -> None:
        if self.setting == 'auto' and (self.mode is not None or self._early):
            self._decide()
        if self.stream is not None:
            self.stream.tick(now)

    # --- decisions ------------------------------------------------------------------------
    def _episode_publishers(self) -> int:
        try:
            return self._node.count_publishers(self._episode_topic)
        except Exception:  # noqa: BLE001 - the context is shutting down
            return 0

    def _decide(self) -> None:
        has_source = self._episode_publishers() > 0
        if self.mode is None and self._layout is None and not has_source:
            return  # no layout and no sign of episodes: detections wait for the layout
        if self.mode is None:
            self._switch(EPISODES if has_source else STREAM, 'first detection')
        elif self.mode == STREAM and has_source:
            self._switch(EPISODES, 'a /road/episode publisher appeared')
        elif self.mode == EPISODES and not has_source:
            sizes = self._node.assembler.buffer_sizes()
            if sizes['open_episodes'] == 0 and sizes['held_without_episode'] == 0:
                self._switch(STREAM, 'no /road/episode publisher and no open episode')

    def _switch(self, mode: str, why: str) -> None:
        old, self.mode = self.mode, mode
        if old is not None:
            self.switches += 1
        if mode == STREAM and self.stream is None:
            self._start_stream()
        if old == STREAM and self.stream is not None:
            self.stream.flush(time.monotonic())
        self._node.get_logger().info(f'mode {mode} ({why})')
        if self._early:
            self._release_early()

    def _start_stream(self) -> None:
        cfg = self._node.config
        settings = StreamSettings(
            method=self._method,
            lag=self._lag,
            segment_size=cfg.segment_size,
            seed=cfg.seed,
            max_buffered=cfg.max_buffered,
            max_uncommitted=self._max_uncommitted,
            quiet_flush=self._quiet_flush,
        )
        log = leveled_log(self._node.get_logger())
        context = self._node.context

        def publish(data: bytes) -> None:
            if context.ok():  # after Ctrl-C the context is gone: nothing left to publish to
                self._publisher.publish(data)
                if self._on_publish is not None:
                    self._on_publish(data)

        self.stream = StreamMode(
            settings,
            cfg.bounds(),
            publish,
            log,
            on_reject=self._node._on_reject,
            publish_handoff=self._publish_handoff,
        )
        stream = self.stream
        self._clock = self._node.create_timer(CLOCK_PERIOD, lambda: stream.clock(time.monotonic()))
        if self._layout is not None:
            self.stream.set_layout(*self._layout)

    # --- diagnostics ----------------------------------------------------------------------
    def diagnostics(self, values: dict[str, Any]) -> None:
        """Add the mode and stream mode's figures to the node's values (counts summed)."""
        values['mode'] = self.mode or 'undecided'
        values['mode_setting'] = self.setting
        values['mode_switches'] = self.switches
        values['held_before_mode'] = len(self._early)
        name = 'handled.before_layout'
        values[name] = int(values.get(name, 0)) + self.early_held
        if self.early_refused:
            values['rejected'] = int(values['rejected']) + self.early_refused
            name = 'rejected.buffer_full'
            values[name] = int(values.get(name, 0)) + self.early_refused
        s = self.stream
        if s is None:
            return
        ingest = s.ingest
        values['received'] = int(values['received']) + ingest.received
        values['accepted'] = int(values['accepted']) + ingest.accepted
        values['rejected'] = int(values['rejected']) + sum(ingest.rejected.values())
        for reason in STREAM_REASONS:
            name = f'rejected.{reason}'
            values[name] = int(values.get(name, 0)) + ingest.rejected.get(reason, 0)
        for reason, count in sorted(ingest.handled.items()):
            values[f'stream.handled.{reason}'] = count
        values.update(s.diagnostics())
        last = ingest.last_rx
        values['stream.idle'] = '' if last is None else f'{time.monotonic() - last:.3f}'

    def close(self) -> None:
        if self.stream is not None:
            self.stream.close()


def leveled_log(logger: Any) -> Callable[[str, str], None]:
    """``log(level, text)`` for code that runs without ROS (the stream mode's threads).

    rclpy refuses one call site that logs at several severities ("Logger severity cannot be
    changed between calls"), so every level has its own call. A log line that comes after the
    context was shut down (a thread finishing during Ctrl-C) is dropped, not raised.
    """

    def log(level: str, text: str) -> None:
        try:
            if level == 'error':
                logger.error(text)
            elif level == 'warning':
                logger.warning(text)
            else:
                logger.info(text)
        except Exception:  # noqa: BLE001 - rclpy's logging is gone with the context
            pass

    return log
