"""Stream mode across a restart of the association node (separate processes).

The node runs in stream mode; two vehicles pass the first two stations, so their tracks are
published CONFIRMED; the node is killed (SIGKILL to its process group: no goodbye) and
started again; a third vehicle passes. The restarted node publishes a later run whose track
ids never meet the earlier ones, and a consumer that keeps the latest state per track id
and applies the track contract's rule (docs/interfaces.md: a track not FINAL in an earlier
run has ended once a message of a later run arrives) sees no track left open once the
restarted node flushed its road.

Every process is started through the ``ros_process`` fixture, which stops it at teardown
even when the test fails.
"""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import Detection, SensorLayout, Track, TrackArray

pytestmark = [pytest.mark.ros, pytest.mark.slow]

IDS = [10, 11, 12, 13]
NAMES = ['r_a', 'r_b', 'r_c', 'r_d']
POS = [100.0, 200.0, 300.0, 400.0]
LAYOUT = Layout(500.0, np.array(POS), np.array(IDS), tuple(NAMES))
#: [s] also the wall time after which a quiet road is flushed: the first node is killed
#: well within it, and no window solve commits anything of its two vehicles before
LAG = 15.0


class Source:
    """The test's node: the layout (latched), the sensors, and a consumer of /mlkm/tracks."""

    def __init__(self, context) -> None:
        self.node = Node('restart_source', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.layout_pub = self.node.create_publisher(
            SensorLayout, qos.LAYOUT_TOPIC, qos.LAYOUT_QOS
        )
        self.det_pubs = [
            self.node.create_publisher(Detection, qos.detections_topic(n), qos.DETECTIONS_QOS)
            for n in NAMES
        ]
        self.tracks: list[TrackArray] = []
        self.node.create_subscription(
            TrackArray, qos.TRACKS_TOPIC, self.tracks.append, qos.TRACKS_QOS
        )
        self.layout_pub.publish(conv.layout_to_msg(LAYOUT, conv.seconds_to_ns(1.0)))

    def endpoints(self) -> set[tuple[str, bytes]]:
        """The node's endpoints seen in the graph: the readers of every sensor's topic and the
        writers of /mlkm/tracks (a restarted node's are new; a killed node's linger until its
        lease ends)."""
        found = set()
        for name in NAMES:
            topic = self.node.resolve_topic_name(qos.detections_topic(name))
            found |= {
                (name, bytes(i.endpoint_gid))
                for i in self.node.get_subscriptions_info_by_topic(topic)
            }
        topic = self.node.resolve_topic_name(qos.TRACKS_TOPIC)
        found |= {
            ('tracks', bytes(i.endpoint_gid))
            for i in self.node.get_publishers_info_by_topic(topic)
        }
        return found

    def vehicle(self, t0: float, speed: float, stations: int) -> None:
        for s in range(stations):
            ns = conv.seconds_to_ns(t0 + POS[s] / speed)
            self.det_pubs[s].publish(conv.detection_to_msg(IDS[s], ns, POS[s], speed, -1))

    def runs(self) -> list[int]:
        return sorted({m.run for m in self.tracks})

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


def consumer_view(messages: list[TrackArray]) -> dict[int, tuple[int, int]]:
    """track id -> (run, status): the latest state of each track, where a track that is not
    FINAL in an earlier run than the newest message's has ended (the track contract in
    docs/interfaces.md, stream mode)."""
    view: dict[int, tuple[int, int]] = {}
    newest = 0
    for msg in messages:
        if msg.run > newest:
            newest = msg.run
            for tid, (run, status) in view.items():
                if run < newest and status != Track.STATUS_FINAL:
                    view[tid] = (run, Track.STATUS_FINAL)
        for t in msg.tracks:
            view[t.track_id] = (msg.run, t.status)
    return view


def start_node(ros_process, quiet_flush: float = 0.0):
    """The node in stream mode; its road flushed after ``quiet_flush`` [s] of quiet wall
    time (0: after the lag)."""
    return ros_process(
        'mlkm_assoc',
        'association_node',
        '--ros-args',
        '-p',
        'mode:=stream',
        '-p',
        f'lag:={LAG}',
        '-p',
        f'quiet_flush:={quiet_flush}',
    )


def test_a_restarted_node_numbers_new_tracks_and_ends_the_old_ones(
    ros_process, rclpy_context, spin_until
) -> None:
    src = Source(rclpy_context)

    def wait(predicate, timeout: float = 120.0, seen=lambda: '') -> None:
        assert spin_until(src.executor, predicate, timeout), f'timed out; {seen()}'

    try:
        first = start_node(ros_process)
        wait(lambda: all(p.get_subscription_count() >= 1 for p in src.det_pubs))
        wait(lambda: src.node.count_publishers(qos.TRACKS_TOPIC) >= 1)
        src.vehicle(10.0, 40.0, 2)  # stamps 12.5 and 15 s
        src.vehicle(12.0, 25.0, 2)  # 16 and 20 s
        wait(
            lambda: (
                [s for _, s in consumer_view(src.tracks).values()].count(Track.STATUS_CONFIRMED)
                == 2
            )
        )
        old = src.endpoints()
        os.killpg(first.pid, signal.SIGKILL)  # the node and its tracker and solver processes
        assert first.wait(30.0) is not None

        start_node(ros_process, quiet_flush=2.0)  # its road is flushed soon after the vehicle
        # every sensor topic and the track topic have the restarted node's endpoints
        wait(lambda: {topic for topic, _ in src.endpoints() - old} == {*NAMES, 'tracks'})
        n_before = len(src.tracks)  # what the dead node published (the new one: no tracks yet)
        third = conv.seconds_to_ns(110.0)
        src.vehicle(110.0, 50.0, 4)
        # the restarted node tracks the vehicle and, once the road is quiet, flushes it
        wait(
            lambda: any(
                t.status == Track.STATUS_FINAL
                and any(conv.time_to_ns(x) > third for x in t.stamps)
                for m in src.tracks[n_before:]
                for t in m.tracks
            ),
            seen=lambda: 'after the restart: ' + repr([
                (m.run, [(t.status, len(t.stamps)) for t in m.tracks])
                for m in src.tracks[n_before:]
            ]),
        )  # fmt: skip
    finally:
        src.close()
    before = [m for m in src.tracks[:n_before] if m.tracks]
    after = src.tracks[n_before:]
    old_ids = {t.track_id for m in before for t in m.tracks}
    new_ids = {t.track_id for m in after for t in m.tracks}
    assert len(old_ids) == 2 and new_ids
    assert not old_ids & new_ids  # never reused across the restart
    (old_run,) = {m.run for m in before}
    (new_run,) = {m.run for m in after}
    assert 0 < old_run < new_run and old_run <= min(old_ids)
    assert max(old_ids) < new_run <= min(new_ids)
    # the dead node's tracks were CONFIRMED when it died; the consumer sees them ended
    assert {s for _, s in consumer_view(before).values()} == {Track.STATUS_CONFIRMED}
    view = consumer_view(src.tracks)
    assert {s for _, s in view.values()} == {Track.STATUS_FINAL}
    assert {tid for tid, (run, _) in view.items() if run == old_run} == old_ids
