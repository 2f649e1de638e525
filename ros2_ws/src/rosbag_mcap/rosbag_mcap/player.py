"""bag_player: replay a bag (directory or lone .mcap, ours or rosbag2's) onto its topics.

    bag_player --ros-args -p bag:=bags/run1 -p rate:=2.0 -p wait_for_subscribers:=1

Every topic is published with the QoS its recorded publishers offered (reliable and
transient_local only when all of them offered it, so latched topics stay latched), as raw CDR
bytes, in log-time order with the recorded spacing divided by ``rate``.

Exit status: 0 the bag was played (or playback was interrupted by SIGINT/SIGTERM);
1 the bag was refused (missing, not a bag, nothing readable, no playable topic);
2 a parameter value was refused; 3 the bag is damaged (truncated or corrupt): the readable
part was played and a warning names the file and the count played.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import rclpy
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future

from mlkm_ros import lifecycle
from mlkm_ros.params import ConfigError, declare_startup
from mlkm_ros.publishing import PublishTimeout, ReliablePublisher
from rosbag_mcap.definitions import DefinitionCache
from rosbag_mcap.metadata import BagError, replay_qos
from rosbag_mcap.migrate import Migration, MigrationError, needs_migration
from rosbag_mcap.reader import BagReader
from rosbag_mcap.ros_glue import (
    EXIT_OK,
    EXIT_PARTIAL,
    EXIT_REFUSED,
    TopicSelection,
    import_message_type,
    profile_from_spec,
    start_tool,
)
from rosbag_mcap.settings import PLAYER_PARAMS

ACK_TIMEOUT = 10.0  # [s] longest wait for subscribers to acknowledge before going on


class RefusedError(Exception):
    """The bag cannot be played; the message says why."""


@dataclass
class _Output:
    topic: str  # as recorded
    name: str  # as published (after remapping)
    publisher: Publisher
    sender: ReliablePublisher  # publishes with back-pressure (mlkm_ros.publishing)
    reliable: bool
    latched: bool
    # recorded with another definition of its type: converts each payload (rosbag_mcap.migrate)
    migrate: Callable[[bytes], bytes] | None = None


def parse_remaps(rules: tuple[str, ...]) -> dict[str, str]:
    remaps = {}
    for rule in rules:
        source, sep, target = rule.partition(':=')
        if not sep or not source or not target:
            raise ConfigError(f"parameter remap entry {rule!r} refused: expected 'from:=to'")
        remaps[source] = target
    return remaps


class BagPlayer(Node):
    """Publishes the messages of one bag; playback runs in its own thread."""

    def __init__(self) -> None:
        super().__init__('bag_player')
        values = declare_startup(self, PLAYER_PARAMS)
        bag: str = values['bag']
        self._rate: float = values['rate']
        self._loop: bool = values['loop']
        self._start_offset: float = values['start_offset']
        self._publish_clock: bool = values['publish_clock']
        self._clock_rate: float = values['clock_rate']
        self._wait_for_subscribers: int = values['wait_for_subscribers']
        self._wait_timeout: float = values['wait_timeout']
        self._linger: float = values['linger']
        if not bag:
            raise ConfigError(
                'parameter bag refused: it is required '
                '(--ros-args -p bag:=<bag directory or .mcap file>)'
            )
        remaps = parse_remaps(values['remap'])
        try:
            selection = TopicSelection(
                values['topics'],
                values['include_regex'],
                values['exclude_regex'],
                include_hidden=True,
            )
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        try:
            self._reader = BagReader(bag)
        except BagError as exc:
            raise RefusedError(str(exc)) from None
        for problem in self._reader.problems:
            self.get_logger().warning(problem)
        self._stop = threading.Event()
        self._outputs: dict[str, _Output] = {}
        definitions = DefinitionCache()
        for info in self._reader.topics.values():
            if not selection.selects(info.name):
                continue
            if info.message_count == 0:
                continue
            try:
                msg_type = import_message_type(info.type)
                migrate = self._migration(info.name, info.type, msg_type, definitions)
            except (ImportError, MigrationError) as exc:
                self.get_logger().warning(f'not playing {info.name}: {exc}')
                continue
            spec = replay_qos(info.offered_qos, info.message_count)
            qos = profile_from_spec(spec)
            name = remaps.get(info.name, info.name)
            publisher = self.create_publisher(msg_type, name, qos)
            self._outputs[info.name] = _Output(
                info.name,
                name,
                publisher,
                ReliablePublisher(publisher, self.context, self._stop),
                qos.reliability == ReliabilityPolicy.RELIABLE,
                qos.durability == DurabilityPolicy.TRANSIENT_LOCAL,
                migrate,
            )
        if not self._outputs:
            raise RefusedError(
                f'{self._reader.path}: no playable topic (bag topics: '
                f'{sorted(self._reader.topics) or "none"})'
            )
        self._clock_pub = None
        if self._publish_clock:
            from rosgraph_msgs.msg import Clock

            self._clock_msg = Clock()
            self._clock_pub = self.create_publisher(Clock, '/clock', QoSProfile(depth=1))
            self.create_timer(1.0 / self._clock_rate, self._tick_clock)
        self._bag_time: int | None = None  # bag time [ns] of the latest published message
        self._time_map: tuple[float, int] | None = None  # (monotonic start, bag start ns)
        self.played = 0
        self.publish_failures = 0
        self.exit_status = EXIT_OK
        self.done = Future()
        self._thread = threading.Thread(target=self._run, name='playback', daemon=True)

    def _migration(
        self, topic: str, type_name: str, msg_type: type, definitions: DefinitionCache
    ) -> Migration | None:
        """A converter when ``topic`` was recorded with another field layout of its type."""
        recorded = self._reader.definition(topic)
        try:
            installed = definitions.full_text(type_name)
        except Exception:  # noqa: BLE001 (no installed .msg text: play the bytes as they are)
            return None
        if not needs_migration(recorded, installed, type_name):
            return None
        self.get_logger().warning(
            f'{topic} was recorded with another definition of {type_name}: its messages are '
            'converted to the installed one (fields it lacks get their defaults)'
        )
        return Migration(recorded, type_name, msg_type)

    # -- playback thread

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)

    def _run(self) -> None:
        try:
            self._play_all()
        except Exception as exc:  # noqa: BLE001  (reported, never a traceback for users)
            if rclpy.ok() and not self._stop.is_set():
                self.get_logger().error(f'playback failed: {type(exc).__name__}: {exc}')
                self.exit_status = EXIT_REFUSED
        finally:
            if not self.done.done():
                self.done.set_result(self.exit_status)

    def _play_all(self) -> None:
        self._wait_for_matching()
        start = self._reader.start_time
        if start is None:
            raise RefusedError(f'{self._reader.path}: no readable message')
        first = start + int(self._start_offset * 1e9)
        total = sum(self._reader.topics[t].message_count for t in self._outputs)
        self.get_logger().info(
            f'playing {self._reader.path} ({total} messages on {len(self._outputs)} topics, '
            f'rate {self._rate:g}{", loop" if self._loop else ""})'
        )
        while not self._stop.is_set():
            self._play_once(first)
            if not self._loop or not rclpy.ok():
                break
        if self._stop.is_set() or not rclpy.ok():
            return  # interrupted: main() reports
        self._await_acks()
        self._report()
        self._linger_for_late_subscribers()

    def _wait_for_matching(self) -> None:
        wanted = self._wait_for_subscribers
        if wanted <= 0:
            return
        limit = self._wait_timeout
        deadline = time.monotonic() + limit if limit > 0 else None
        announced = False
        while not self._stop.is_set():
            # Latched topics reach late subscribers anyway: only volatile ones are waited for.
            missing = [
                o.name
                for o in self._outputs.values()
                if not o.latched and o.publisher.get_subscription_count() < wanted
            ]
            if not missing:
                return
            if not announced:
                self.get_logger().info(
                    f'waiting for {wanted} subscriber(s) on {len(missing)} topic(s)'
                    + (f' (at most {limit:g} s)' if deadline is not None else '')
                )
                announced = True
            if deadline is not None and time.monotonic() >= deadline:
                self.get_logger().warning(
                    f'playing although fewer than {wanted} subscribers matched after '
                    f'{self._wait_timeout:g} s on: {", ".join(sorted(missing))}'
                )
                return
            self._stop.wait(0.02)

    def _play_once(self, first: int) -> None:
        wall_start = time.monotonic()
        self._time_map = (wall_start, first)
        for message in self._reader.messages(topics=self._outputs, start_time=first):
            if self._stop.is_set() or not rclpy.ok():
                return
            if self._rate > 0:
                due = wall_start + (message.log_time - first) / 1e9 / self._rate
                delay = due - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    return
            output = self._outputs[message.topic]
            self._bag_time = message.log_time
            self._publish(output, message.data)

    def _publish(self, output: _Output, data: bytes) -> None:
        payload = data if isinstance(data, bytes) else bytes(data)
        if output.migrate is not None:
            try:
                payload = output.migrate(payload)
            except MigrationError as exc:
                self.publish_failures += 1
                self.get_logger().error(f'dropped a message on {output.name}: {exc}')
                return
        try:
            if output.sender.publish(payload):
                self.played += 1
        except PublishTimeout as exc:  # subscribers acknowledged nothing for minutes
            self.publish_failures += 1
            self.get_logger().error(f'dropped a message on {output.name}: {exc}')

    def _await_acks(self) -> None:
        """Wait until reliable subscribers acknowledged what was published (bounded)."""
        for output in self._outputs.values():
            if output.reliable and rclpy.ok() and not self._stop.is_set():
                if not output.sender.wait_acked(ACK_TIMEOUT):
                    self.get_logger().warning(
                        f'{output.name}: not every subscriber acknowledged within '
                        f'{ACK_TIMEOUT:g} s'
                    )

    def _report(self) -> None:
        reader = self._reader
        if self.publish_failures:
            self.exit_status = EXIT_PARTIAL
        if reader.complete and not reader.problems:
            self.get_logger().info(f'played {self.played} messages from {reader.path}')
            return
        expected = reader.expected_message_count
        of = f' of {expected} recorded' if expected is not None else ''
        files = ', '.join(str(f) for f in reader.files)
        damaged = not reader.complete or any('corrupt' in p for p in reader.problems)
        if damaged:
            self.exit_status = EXIT_PARTIAL
            self.get_logger().warning(
                f'bag damaged: played the readable part, {self.played} messages{of}: '
                f'{"; ".join(reader.problems)}'
            )
        else:
            self.get_logger().info(f'played {self.played} messages{of} from {files}')

    def _linger_for_late_subscribers(self) -> None:
        if self._linger < 0:
            self.get_logger().info('playback done; staying up until interrupted')
            self._stop.wait()
        elif self._linger > 0:
            self._stop.wait(self._linger)

    # -- clock (executor thread)

    def _tick_clock(self) -> None:
        if self._clock_pub is None or self._time_map is None:
            return
        if self._rate > 0:
            wall_start, first = self._time_map
            now = first + int((time.monotonic() - wall_start) * self._rate * 1e9)
        else:
            now = self._bag_time
        if now is None:
            return
        self._clock_msg.clock.sec, self._clock_msg.clock.nanosec = divmod(now, 1_000_000_000)
        self._clock_pub.publish(self._clock_msg)


def main(args: list[str] | None = None) -> int:
    # Ctrl-C and SIGTERM only end the spin (mlkm_ros.lifecycle): exit 0, no traceback
    with lifecycle.stop_signals():
        node, status = start_tool(
            'bag_player', BagPlayer, args, RefusedError, 'refusing to play: '
        )
        if node is None:
            return status
        node.start()
        try:
            lifecycle.spin(node, until=node.done.done)
            if node.done.done():
                status = node.exit_status
            else:
                print(f'bag_player: interrupted after {node.played} messages', file=sys.stderr)
                status = EXIT_OK
        finally:
            node.stop()
            node.destroy_node()
            rclpy.try_shutdown()
    return status


if __name__ == '__main__':
    sys.exit(main())
