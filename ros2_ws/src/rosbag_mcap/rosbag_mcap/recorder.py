"""bag_recorder: record topics into a bag in rosbag2's MCAP layout.

    bag_recorder --ros-args -p output:=bags/run1 -p include_regex:='^/road/'

Topics are discovered by polling the graph every ``discovery_period`` seconds, so topics that
appear later are recorded too. Each topic is subscribed raw (the CDR bytes are written as
received) with history keep_all, reliable / transient_local when every publisher offers it
(latched messages published before the recorder started are captured).

SIGINT and SIGTERM stop the recording cleanly: the messages already delivered are drained,
the MCAP gets its summary and index, metadata.yaml is written and a per-topic count logged.

A failed write (full disk, I/O error) ends the recording at once: the bag keeps every message
that reached the disk (finished MCAP and metadata.yaml, see storage.BagWriter), the error is
logged and the exit status is 4.
"""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.subscription import Subscription
from rclpy.task import Future

from mlkm_ros.params import ConfigError, declare_startup
from rosbag_mcap.definitions import DefinitionCache, DefinitionNotFoundError
from rosbag_mcap.ros_glue import (
    EXIT_WRITE_FAILED,
    TopicSelection,
    import_message_type,
    request_profile,
    spec_from_profile,
    start_tool,
)
from rosbag_mcap.settings import RECORDER_PARAMS
from rosbag_mcap.storage import BagError, BagWriteError, BagWriter, default_bag_name


class BagRecorder(Node):
    """Subscribes to the selected topics and writes every message to one bag."""

    def __init__(self) -> None:
        super().__init__('bag_recorder')
        values = declare_startup(self, RECORDER_PARAMS)
        output, compression = values['output'], values['compression']
        self._discovery_period: float = values['discovery_period']
        self._flush_period: float = values['flush_period']
        self._max_duration: float = values['max_duration']
        self._stop_drain_timeout: float = values['stop_drain_timeout']
        self._stop_idle: float = values['stop_idle']
        try:
            self._selection = TopicSelection(
                values['topics'],
                values['include_regex'],
                values['exclude_regex'],
                values['include_hidden_topics'],
            )
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        if compression not in ('zstd', 'lz4', 'none'):
            raise ConfigError(
                f'parameter compression={compression!r} refused: expected zstd, lz4 or none'
            )
        self._output = Path(output) if output else Path('bags') / default_bag_name()
        self._writer = BagWriter(
            self._output, compression=compression, chunk_size=values['chunk_size']
        )
        self._use_sim_time = bool(self.get_parameter('use_sim_time').value)
        self._definitions = DefinitionCache()
        self._recording: dict[str, Subscription] = {}
        self._skipped: set[str] = set()
        self._stop_signal: int | None = None
        self.failed = False
        self.finished = Future()
        self._started = time.monotonic()
        self._discover()
        self._discovery_timer = self.create_timer(self._discovery_period, self._discover)
        # Signal handlers only set a flag; this timer turns it into the end of spinning.
        self._stop_timer = self.create_timer(0.1, self._check_stop)
        self._flush_timer = (
            self.create_timer(self._flush_period, self._flush) if self._flush_period > 0 else None
        )
        self.get_logger().info(
            f'recording to {self._output.resolve()} ({self._describe_selection()})'
        )

    # -- discovery and recording

    def _describe_selection(self) -> str:
        s = self._selection
        parts = []
        if s.topics:
            parts.append(f'topics {list(s.topics)}')
        if s.include_regex:
            parts.append(f'include {s.include_regex!r}')
        if not parts:
            parts.append('all topics')
        if s.exclude_regex:
            parts.append(f'exclude {s.exclude_regex!r}')
        return ', '.join(parts)

    def _skip(self, topic: str, reason: str) -> None:
        if topic not in self._skipped:
            self._skipped.add(topic)
            self.get_logger().warning(f'not recording {topic}: {reason}')

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic in self._recording or topic in self._skipped:
                continue
            if not self._selection.selects(topic):
                continue
            if len(types) != 1:
                self._skip(topic, f'it has several types {types}')
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # only subscribers so far: wait for a publisher to learn its QoS
            self._subscribe(topic, types[0], publishers)

    def _subscribe(self, topic: str, type_name: str, publishers: list) -> None:
        try:
            msg_type = import_message_type(type_name)
            definition = self._definitions.full_text(type_name)
        except (ImportError, DefinitionNotFoundError, ValueError, OSError) as exc:
            self._skip(topic, str(exc))
            return
        type_hash = next(
            (
                str(p.topic_type_hash)
                for p in publishers
                if str(p.topic_type_hash).startswith('RIHS01_')
            ),
            '',
        )
        offered = [spec_from_profile(p.qos_profile) for p in publishers]
        qos = request_profile(publishers)
        try:
            subscription = self.create_subscription(
                msg_type, topic, self._make_callback(topic), qos, raw=True
            )
        except Exception as exc:  # noqa: BLE001  (rclpy raises several types; report, go on)
            self._skip(topic, f'cannot subscribe: {exc}')
            return
        try:
            self._writer.add_topic(topic, type_name, definition, offered, type_hash)
        except BagWriteError as exc:
            self.destroy_subscription(subscription)
            self._write_failed(exc)
            return
        self._recording[topic] = subscription
        self.get_logger().info(
            f'recording {topic} [{type_name}] {qos.reliability.name.lower()}, '
            f'{qos.durability.name.lower()}'
        )

    def _make_callback(self, topic: str):
        writer = self._writer
        clock = self.get_clock()
        use_sim_time = self._use_sim_time

        def on_message(data: bytes, info: dict) -> None:
            if writer.failure is not None:
                return  # the recording has ended; spinning stops at once
            received = (
                clock.now().nanoseconds
                if use_sim_time
                else (info.get('received_timestamp') or time.time_ns())
            )
            sent = info.get('source_timestamp') or received
            try:
                writer.write(
                    topic, data, received, sent, info.get('publication_sequence_number') or 0
                )
            except BagWriteError as exc:
                self._write_failed(exc)

        return on_message

    def _flush(self) -> None:
        try:
            self._writer.flush()
        except BagWriteError as exc:
            self._write_failed(exc)

    def _write_failed(self, exc: BagWriteError) -> None:
        """Stop recording: nothing more can be written (the bag is finished in close())."""
        if not self.failed:
            self.failed = True
            self.get_logger().error(f'recording failed: {exc}; stopping')
        if not self.finished.done():
            self.finished.set_result('write failed')

    # -- stopping

    def request_stop(self, signum: int, _frame: object = None) -> None:
        """Signal handler: only records the request (it may run inside any callback)."""
        self._stop_signal = signum

    def _check_stop(self) -> None:
        if self.finished.done():
            return
        if self._stop_signal is not None:
            self.finished.set_result(signal.Signals(self._stop_signal).name)
        elif self._max_duration > 0 and time.monotonic() - self._started >= self._max_duration:
            self.finished.set_result('max_duration')

    def drain(self) -> None:
        """Take the messages already delivered to the subscriptions (context still valid).

        A recorder that fell behind a fast publisher still has a backlog when it is told to
        stop; it is taken whole until the subscriptions stay idle for ``stop_idle`` seconds,
        at most ``stop_drain_timeout``. A second SIGINT/SIGTERM ends the drain at once.
        """
        for timer in (self._discovery_timer, self._stop_timer, self._flush_timer):
            if timer is not None:
                timer.cancel()
        if not rclpy.ok() or self.failed:
            return
        first_signal = self._stop_signal
        self._stop_signal = None
        now = time.monotonic()
        deadline = now + self._stop_drain_timeout
        last_message = now
        while now < deadline and now - last_message < self._stop_idle:
            if self._stop_signal is not None:
                self.get_logger().warning(
                    'second stop signal: closing the bag without taking the remaining messages'
                )
                break
            before = self._writer.message_count
            rclpy.spin_once(self, timeout_sec=0.02)
            now = time.monotonic()
            if self._writer.message_count != before:
                last_message = now
        else:
            if now >= deadline:
                self.get_logger().warning(
                    f'stop_drain_timeout ({self._stop_drain_timeout:g} s) reached while '
                    'messages were still arriving; closing the bag'
                )
        self._stop_signal = first_signal

    def close(self) -> None:
        """Finish the bag and log where it is and how many messages each topic has."""
        if self._writer.closed:
            return
        try:
            info = self._writer.close()
        except BagWriteError as exc:
            self.failed = True
            self.get_logger().error(str(exc))
            return
        counts = {
            t['topic_metadata']['name']: t['message_count']
            for t in info['topics_with_message_count']
        }
        lines = [f'  {name}: {count}' for name, count in sorted(counts.items())]
        if self._writer.failure is not None:
            self.failed = True
            self.get_logger().error(
                f'recording failed: {self._writer.failure}; the bag keeps the '
                f'{info["message_count"]} messages written before the failure (finished, with '
                f'metadata.yaml): {self._output.resolve()}'
                + ('\n' + '\n'.join(lines) if lines else '')
            )
            return
        self.get_logger().info(
            f'bag written: {self._output.resolve()} ({info["message_count"]} messages, '
            f'{len(counts)} topics)' + ('\n' + '\n'.join(lines) if lines else '')
        )


def main(args: list[str] | None = None) -> int:
    # Our own SIGINT/SIGTERM handlers: rclpy's would shut the context down at once, before
    # the messages already delivered could be taken and the bag closed.
    # The constructor already subscribes, so a publisher may see the recorder and stop it
    # before the constructor returns: hold such a signal until the node can take it.
    early: list[int] = []
    signal.signal(signal.SIGINT, lambda signum, _frame: early.append(signum))
    signal.signal(signal.SIGTERM, lambda signum, _frame: early.append(signum))
    node, status = start_tool('bag_recorder', BagRecorder, args, BagError, 'cannot record: ')
    if node is None:
        return status
    signal.signal(signal.SIGINT, node.request_stop)
    signal.signal(signal.SIGTERM, node.request_stop)
    if early:
        node.request_stop(early[0])
    try:
        rclpy.spin_until_future_complete(node, node.finished)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        try:
            node.drain()
        finally:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            node.close()
            if node.failed:
                status = EXIT_WRITE_FAILED
            node.destroy_node()
            rclpy.try_shutdown()
    return status


if __name__ == '__main__':
    sys.exit(main())
