"""Which mode the association node works in: episodes (the paper's closed world) or stream.

``mode`` parameter: ``episodes`` or ``stream`` fixes it; ``auto`` (the default) follows the
source. A source with episodes publishes /road/episode; a continuous source has no such
publisher. So ``auto`` is decided at the first detection: episodes when /road/episode has a
publisher (or an EpisodeInfo arrived), stream otherwise. It is checked again every tick: an
episode publisher appearing (or an EpisodeInfo) switches to episodes at once, after the
stream was flushed (its tracks become FINAL); the publisher gone and every episode finished
switches back to stream.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from rclpy.publisher import Publisher

from mlkm_assoc.stream_mode import REJECT_REASONS as STREAM_REASONS
from mlkm_assoc.stream_mode import StreamMode, StreamSettings
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import Detection, SensorLayout

MODES = ('auto', 'episodes', 'stream')
#: Period of the clock ticks stream mode's reorder buffer runs on while nothing arrives [s].
CLOCK_PERIOD = 0.02
EPISODES, STREAM = 'episodes', 'stream'
#: Longest wait for the tracker process at the start of a node in stream mode [s].
READY_TIMEOUT = 60.0


class ModeSwitch:
    """Owns stream mode (created when first needed) and tells the node where input goes."""

    def __init__(
        self, node: Node, publisher: Publisher, mode: str, lag: float, method: str
    ) -> None:
        self._node = node
        self._publisher = publisher
        self.setting = mode
        self._lag = lag
        self._method = method
        self._episode_topic = node.resolve_topic_name(qos.EPISODE_TOPIC)
        self.mode: str | None = None if mode == 'auto' else mode
        self._layout: tuple | None = None
        self.stream: StreamMode | None = None
        self.switches = 0
        if self.mode == STREAM:
            # subscribe only once the tracker process is warm: detections arriving while it
            # starts (a second or two of imports) would all wait for it
            self._start_stream()
            t0 = time.monotonic()
            if self.stream.wait_ready(READY_TIMEOUT):
                node.get_logger().info(
                    f'stream mode: tracker ready after {time.monotonic() - t0:.1f} s'
                )
            else:
                node.get_logger().warning(
                    f'stream mode: the tracker process is not ready after {READY_TIMEOUT:g} s;'
                    ' detections wait for it'
                )

    # --- inputs from the node -------------------------------------------------------------
    def layout(self, msg: SensorLayout, layout, lane_counts) -> None:
        """A new layout (already validated)."""
        entries, exits = conv.layout_ramps(msg)
        self._layout = (layout, lane_counts, entries, exits)
        if self.stream is not None:
            self.stream.set_layout(*self._layout)

    def episode_info(self) -> None:
        """An EpisodeInfo arrived: the source has episodes."""
        if self.setting == 'auto' and self.mode != EPISODES:
            self._switch(EPISODES, 'an EpisodeInfo arrived')

    def take_detection(self, msg: Detection) -> bool:
        """True when stream mode took the detection; False: episodes mode's."""
        if self.mode is None:
            self._decide()
        if self.mode != STREAM:
            return False
        self.stream.ingest.bounds = self._node.assembler.bounds  # live parameter changes
        stamp = msg.header.stamp
        self.stream.add(
            msg.sensor_id,
            stamp.sec * conv.NS_PER_S + stamp.nanosec,
            msg.position,
            msg.velocity,
            msg.lane,
            conv.detection_length(msg),
            time.monotonic(),
        )
        return True

    def tick(self, now: float) -> None:
        if self.setting == 'auto' and self.mode is not None:
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

    def _start_stream(self) -> None:
        cfg = self._node.config
        settings = StreamSettings(
            method=self._method,
            lag=self._lag,
            segment_size=cfg.segment_size,
            seed=cfg.seed,
            max_buffered=cfg.max_buffered,
        )
        log = leveled_log(self._node.get_logger())
        context = self._node.context

        def publish(data: bytes) -> None:
            if context.ok():  # after Ctrl-C the context is gone: nothing left to publish to
                self._publisher.publish(data)

        self.stream = StreamMode(
            settings, cfg.bounds(), publish, log, on_reject=self._node._on_reject
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
