"""Back-pressure: a slow subscriber slows a reliable KEEP_ALL publisher down, never breaks it.

Unit tests of ``mlkm_ros.publishing.ReliablePublisher`` on a fake rclpy publisher, and a
multi-process run of sensor_sim at real_time_factor 0 against a deliberately slow
ground-truth subscriber.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from rclpy._rclpy_pybind11 import RCLError

from mlkm_core.simulator import SimConfig, simulate_episodes
from mlkm_ros.publishing import PublishTimeout, ReliablePublisher

HERE = Path(__file__).resolve().parent


class FakeContext:
    def __init__(self) -> None:
        self.up = True

    def ok(self) -> bool:
        return self.up


class FakePublisher:
    """Refuses ``refusals`` publishes like a full Fast DDS writer, then accepts everything."""

    topic_name = '/fake'

    def __init__(self, refusals: int = 0, acked: bool = True) -> None:
        self.refusals = refusals
        self.acked = acked
        self.sent: list[object] = []
        self.ack_waits = 0

    def publish(self, msg: object) -> None:
        if self.refusals > 0:
            self.refusals -= 1
            raise RCLError('Failed to publish: cannot publish data, at ./src/rcl/publisher.c')
        self.sent.append(msg)

    def wait_for_all_acked(self, timeout) -> bool:  # noqa: ANN001 - rclpy Duration
        self.ack_waits += 1
        return self.acked


def test_a_refused_publish_is_retried_until_accepted_and_counted() -> None:
    fake = FakePublisher(refusals=3)
    pub = ReliablePublisher(fake, FakeContext(), sleep=lambda _s: None)
    assert pub.publish('m0') is True
    assert pub.publish('m1') is True
    assert fake.sent == ['m0', 'm1']  # nothing lost, nothing duplicated
    assert pub.retries == 3
    assert pub.published == 2


def test_a_publisher_whose_readers_never_acknowledge_gives_up_with_a_clear_error() -> None:
    fake = FakePublisher(refusals=10**9, acked=False)
    pub = ReliablePublisher(fake, FakeContext(), deadline=0.3, sleep=lambda _s: None)
    with pytest.raises(PublishTimeout, match=r'/fake: the middleware refused a message for'):
        pub.publish('m')
    assert fake.sent == []


def test_a_stop_request_ends_the_retries_without_an_error() -> None:
    fake = FakePublisher(refusals=10**9, acked=False)
    stop = threading.Event()
    pub = ReliablePublisher(fake, FakeContext(), stop, deadline=3600.0)
    threading.Timer(0.3, stop.set).start()
    assert pub.publish('m') is False


def test_a_shut_down_context_is_an_interruption_not_an_error() -> None:
    fake = FakePublisher(refusals=1)
    ctx = FakeContext()
    ctx.up = False
    assert ReliablePublisher(fake, ctx).publish('m') is False


def test_flow_control_waits_for_acknowledgements_every_window_messages() -> None:
    fake = FakePublisher()
    pub = ReliablePublisher(fake, FakeContext(), window=10)
    for i in range(35):
        assert pub.publish(i)
    assert fake.sent == list(range(35))
    assert pub.window_waits == 3  # before messages 10, 20 and 30
    assert fake.ack_waits == 3


def _expected_truth(episodes: int, seed: int) -> int:
    return sum(len(d.detections) for d in simulate_episodes(SimConfig(), seed, episodes, 10.0))


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.timeout(960)  # its own waits allow 900 s: on a saturated machine it takes minutes
def test_sensor_sim_at_full_speed_waits_for_a_slow_truth_subscriber(
    ros_process, ros_env, tmp_path
) -> None:
    # 10,000 ground-truth messages: twice Fast DDS's KEEP_ALL history limit (5,000 samples)
    # and ten flow-control windows
    episodes, seed = 10, 3
    expected = _expected_truth(episodes, seed)
    assert expected == 10 * 50 * 20
    log = open(tmp_path / 'slow_sub.log', 'wb')  # noqa: SIM115 - closed below
    sub = subprocess.Popen(
        # 0.5 ms per message, a 0.5 s stall every 500 messages, gives up after 120 s idle.
        [sys.executable, str(HERE / 'slow_truth_subscriber.py'), str(expected)]
        + ['0.0005', '0.5', '120'],
        env=ros_env,
        stdin=subprocess.DEVNULL,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        sim = ros_process(
            'road_sensors',
            'sensor_sim',
            '--ros-args',
            '-p', f'episodes:={episodes}',
            '-p', f'seed:={seed}',
            '-p', 'real_time_factor:=0.0',
            '-p', 'wait_for_subscribers:=0',
            '-p', 'wait_for_truth_subscribers:=1',
            '-p', 'wait_timeout:=120.0',
            '-p', 'ack_timeout:=300.0',
        )  # fmt: skip
        code = sim.proc.wait(timeout=900)
        assert code == 0, sim.output()
        assert 'Failed to publish' not in sim.output()
        sub.wait(timeout=300)
        out = (tmp_path / 'slow_sub.log').read_text()
        last = out.strip().splitlines()[-1]
        assert last == f'received {expected} distinct {expected} negative_stamps 0', out
    finally:
        if sub.poll() is None:
            os.killpg(sub.pid, signal.SIGKILL)
            sub.wait()
        log.close()


@pytest.mark.ros
def test_ctrl_c_while_waiting_for_subscribers_exits_cleanly(ros_process) -> None:
    # Many sensors make the subscriber count take a while, so SIGINT lands inside it often.
    for attempt in range(6):
        sim = ros_process(
            'road_sensors',
            'sensor_sim',
            '--ros-args',
            '-p', 'n_sensors:=400',
            '-p', 'n_targets:=2',
            '-p', 'episodes:=1',
            '-p', 'wait_for_subscribers:=5',
            '-p', 'wait_timeout:=0.0',
        )  # fmt: skip
        assert sim.wait_for_output('waiting for 5 subscriber(s)', timeout=120), sim.output()
        time.sleep(0.1 * attempt)
        sim.proc.send_signal(signal.SIGINT)
        code = sim.proc.wait(timeout=60)
        out = sim.output()
        assert code == 0, out
        assert 'RCLError' not in out and 'Traceback' not in out, out


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_stalled_handoff_reader_loses_no_handoff(rclpy_context, ros_env, tmp_path) -> None:
    # The hand-off is KEEP_LAST (a late joiner gets the last HANDOFF_HISTORY_DEPTH). Its
    # readers keep everything and the writer's flow-control window stays below the depth:
    # with a KEEP_LAST reader, or a writer without the window, a reader that takes nothing
    # for a few seconds ends up with the newest 1,000 of these 3,000 messages.
    from rclpy.node import Node

    from mlkm_assoc.shard_link import handoff_publisher
    from mlkm_ros import qos
    from road_sensor_msgs.msg import TrackHandoff

    expected = 3 * qos.HANDOFF_HISTORY_DEPTH
    log = open(tmp_path / 'stalled_reader.log', 'wb')  # noqa: SIM115 - closed below
    sub = subprocess.Popen(
        [sys.executable, str(HERE / 'stalled_handoff_reader.py'), str(expected), '5', '60'],
        env=ros_env,
        stdin=subprocess.DEVNULL,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    node = Node('handoff_writer', context=rclpy_context)
    try:
        pub = handoff_publisher(node)
        deadline = time.monotonic() + 120
        while pub.get_subscription_count() < 1:
            assert time.monotonic() < deadline, (tmp_path / 'stalled_reader.log').read_text()
            time.sleep(0.01)
        for run in range(expected):
            assert pub.publish(TrackHandoff(shard=0, shard_count=2, run=run))
        assert pub.window_waits >= 1  # the window held the writer back for the reader
        sub.wait(timeout=300)
        out = (tmp_path / 'stalled_reader.log').read_text()
        assert out.strip().splitlines()[-1] == f'received {expected} distinct {expected}', out
    finally:
        node.destroy_node()
        if sub.poll() is None:
            os.killpg(sub.pid, signal.SIGKILL)
            sub.wait()
        log.close()
