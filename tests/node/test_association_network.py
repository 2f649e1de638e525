"""In-process tests of the association node on a road network (a SensorLayout in its network
form): a hand-made diverge where two vehicles swap order and take different roads, so that
the right tracks are certain; detections checked against their station's position along its
link and its lane count; a method that does not associate networks reports every detection
unassigned; stream mode ends with the same two tracks once the road falls quiet; with link
shapes in the layout, /mlkm/markers draws the links and places each track on its link.
"""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from visualization_msgs.msg import Marker, MarkerArray

from mlkm_assoc.association_node import AssociationNode
from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_ros.network_conversions import network_to_msg
from road_sensor_msgs.msg import Detection, EpisodeInfo, SensorLayout, Track, TrackArray

pytestmark = pytest.mark.ros

IDS = [20, 21, 22, 23]
NAMES = ['n_a', 'n_b', 'n_c', 'n_d']
# link 0 (1000 m) splits into links 1 and 2 (600 m each); stations a, b on link 0, c on
# link 1, d on link 2; c watches one lane, d does not say how many it watches
NETWORK = RoadNetwork(
    links=(RoadLink(0, 'main', 1000.0, 2), RoadLink(1, 'left', 600.0, 1),
           RoadLink(2, 'right', 600.0, 1)),
    connections=((0, 1), (0, 2)),
    station_ids=np.array(IDS),
    station_names=tuple(NAMES),
    station_links=np.array([0, 0, 1, 2]),
    station_offsets=np.array([300.0, 800.0, 200.0, 300.0]),
    station_lanes=np.array([2, 2, 1, 0]),
)  # fmt: skip
OFFSET = 10.0  # [s]
# A (20 m/s) leads at a and b and turns onto link 1; B (25 m/s) passes A after the diverge
# and turns onto link 2: (station index, stamp [s], speed [m/s], lane)
A = [(0, 0.0, 20.0, 0), (1, 25.0, 20.0, 0), (2, 45.0, 20.0, 0)]
B = [(0, 2.0, 25.0, 1), (1, 22.1, 25.0, 1), (3, 42.1, 25.0, 3)]


def ns(t: float) -> int:
    return conv.seconds_to_ns(OFFSET + t)


class Harness:
    """The association node and a test node publishing the network's topics."""

    def __init__(self, context, spin_until, **params) -> None:
        overrides = [Parameter('completion_timeout', value=1.0)]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        self.node = AssociationNode(context=context, parameter_overrides=overrides)
        self.test = Node('network_test', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        for n in (self.node, self.test):
            self.executor.add_node(n)
        self.spin_until = spin_until
        pub = self.test.create_publisher
        self.layout_pub = pub(SensorLayout, qos.LAYOUT_TOPIC, qos.LAYOUT_QOS)
        self.episode_pub = pub(EpisodeInfo, qos.EPISODE_TOPIC, qos.EPISODE_QOS)
        self.det_pubs = [
            pub(Detection, qos.detections_topic(n), qos.DETECTIONS_QOS) for n in NAMES
        ]
        self.tracks: list[TrackArray] = []
        self.test.create_subscription(
            TrackArray, qos.TRACKS_TOPIC, self.tracks.append, qos.TRACKS_QOS
        )

    def wait(self, predicate, timeout: float = 120.0) -> None:
        # an upper bound only: the solver process may take a minute to start on a busy machine
        assert self.spin_until(self.executor, predicate, timeout), 'timed out'

    def detect(self, s: int, t: float, v: float, lane: int, position: float | None = None):
        at = float(NETWORK.station_offsets[s]) if position is None else position
        self.det_pubs[s].publish(conv.detection_to_msg(IDS[s], ns(t), at, v, lane))

    def final(self) -> TrackArray | None:
        return next((m for m in self.tracks if m.final), None)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.test.destroy_node()


@pytest.fixture
def harness(rclpy_context, spin_until):
    made = []

    def make(**params) -> Harness:
        h = Harness(rclpy_context, spin_until, **params)
        made.append(h)
        return h

    yield make
    for h in made:
        h.close()


def run_episode(h: Harness, extra=(), network: RoadNetwork = NETWORK) -> TrackArray:
    """Publish ``network``, one episode with A, B and ``extra`` (station, t, v, lane,
    position) detections; the final TrackArray."""
    h.layout_pub.publish(network_to_msg(network, 0))
    h.wait(lambda: h.node.assembler.layout is not None)
    h.wait(lambda: all(p.get_subscription_count() >= 1 for p in h.det_pubs))
    start, end = ns(-1.0), ns(60.0)
    h.episode_pub.publish(conv.episode_started_msg(0, 2, start, end, 0))
    h.wait(lambda: h.node.assembler.knows_episode(0))
    for s, t, v, lane in sorted(A + B, key=lambda p: p[1]):
        h.detect(s, t, v, lane)
    for s, t, v, lane, position in extra:
        h.detect(s, t, v, lane, position)
    counts = {IDS[s]: n for s, n in enumerate(np.bincount([p[0] for p in A + B], minlength=4))}
    for s, *_ in extra:
        counts[IDS[s]] += 1
    h.episode_pub.publish(conv.episode_ended_msg(0, 2, start, end, 0, counts))
    h.wait(lambda: h.final() is not None)
    return h.final()


def tracks_of(msg: TrackArray) -> list[list[tuple[int, float, float]]]:
    """Each track's (sensor id, stamp [s] in the episode, position [m]), sorted."""
    out = []
    for track in msg.tracks:
        stamps = [conv.time_to_ns(t) / conv.NS_PER_S - OFFSET for t in track.stamps]
        out.append(
            sorted(
                (int(i), round(t, 3), float(x))
                for i, t, x in zip(track.sensor_ids, stamps, track.positions, strict=True)
            )
        )
    return sorted(out)


def test_two_vehicles_that_swap_at_a_diverge_keep_their_tracks(harness) -> None:
    h = harness(method='assignment')
    final = run_episode(
        h,
        extra=[
            (2, 30.0, 20.0, 0, 250.0),  # not where station c stands on its link
            (2, 31.0, 20.0, 1, None),  # lane 1 at a station that watches one lane
        ],
    )
    assert tracks_of(final) == sorted(
        [
            [(IDS[s], t, float(NETWORK.station_offsets[s])) for s, t, _, _ in A],
            [(IDS[s], t, float(NETWORK.station_offsets[s])) for s, t, _, _ in B],
        ]
    )
    assert list(final.unassigned_sensor_ids) == []
    assert h.node.assembler.rejected['position_mismatch'] == 1
    assert h.node.assembler.rejected['lane_out_of_range'] == 1
    # lane 3 at station d, whose lane count the network does not give, was accepted
    assert h.node.assembler.accepted == len(A) + len(B)


def test_a_method_of_one_road_reports_every_detection_unassigned(harness) -> None:
    h = harness(method='mlkm')
    final = run_episode(h)
    assert len(final.tracks) == 0
    got = zip(final.unassigned_sensor_ids, final.unassigned_stamps, strict=True)
    assert sorted((int(i), conv.time_to_ns(t)) for i, t in got) == sorted(
        (IDS[s], ns(t)) for s, t, _, _ in A + B
    )


def test_stream_mode_on_a_network_ends_with_the_two_tracks(harness) -> None:
    # stream mode (the harness's /road/episode publisher would make auto take episodes); the
    # road falls quiet for `lag` seconds of wall time, so every track is committed and FINAL
    h = harness(mode='stream', lag=1.0)
    h.layout_pub.publish(network_to_msg(NETWORK, 0))
    h.wait(lambda: all(p.get_subscription_count() >= 1 for p in h.det_pubs))
    for s, t, v, lane in sorted(A + B, key=lambda p: p[1]):
        h.detect(s, t, v, lane)
    latest: dict[int, Track] = {}

    def final() -> bool:
        for msg in h.tracks:
            # linked by the network's stream, whatever stream_method says (multiframe)
            assert msg.mode == TrackArray.MODE_STREAM and msg.method == 'assignment'
            for track in msg.tracks:
                latest[track.track_id] = track
        h.tracks.clear()
        done = [t for t in latest.values() if t.status == Track.STATUS_FINAL and t.sensor_ids]
        return sum(len(t.sensor_ids) for t in done) == len(A) + len(B)

    h.wait(final)
    done = [t for t in latest.values() if t.status == Track.STATUS_FINAL and t.sensor_ids]
    msg = TrackArray(tracks=done)
    assert tracks_of(msg) == sorted(
        [
            [(IDS[s], t, float(NETWORK.station_offsets[s])) for s, t, _, _ in A],
            [(IDS[s], t, float(NETWORK.station_offsets[s])) for s, t, _, _ in B],
        ]
    )


def test_markers_draw_a_network_with_shapes_and_its_tracks_on_their_links(harness) -> None:
    # 'main' runs east from (0, 0); 'left' turns north at its end, 'right' south
    shapes = {0: ((0.0, 0.0), (1000.0, 0.0)), 1: ((1000.0, 0.0), (1000.0, 600.0)),
              2: ((1000.0, 0.0), (1000.0, -600.0))}  # fmt: skip
    links = tuple(RoadLink(k.link_id, k.name, k.length, k.lanes, shapes[k.link_id])
                  for k in NETWORK.links)  # fmt: skip
    n = NETWORK
    shaped = RoadNetwork(links, n.connections, n.station_ids, n.station_names,
                         n.station_links, n.station_offsets, n.station_lanes)  # fmt: skip
    h = harness(method='assignment', markers_rate=50.0)
    arrays: list[MarkerArray] = []
    h.test.create_subscription(MarkerArray, qos.MARKERS_TOPIC, arrays.append, qos.MARKERS_QOS)
    final = run_episode(h, network=shaped)

    def drawn(array: MarkerArray) -> dict[str, dict[int, Marker]]:
        by_ns: dict[str, dict[int, Marker]] = {}
        for m in array.markers[1:]:
            by_ns.setdefault(m.ns, {})[m.id] = m
        return by_ns

    def final_picture() -> bool:
        return any('final' in m.text for a in arrays for m in a.markers if m.ns == 'status')

    h.wait(final_picture)
    array = next(
        a for a in arrays if any('final' in m.text for m in a.markers if m.ns == 'status')
    )
    by_ns = drawn(array)
    assert [[(p.x, p.y) for p in by_ns['links'][i].points] for i in range(3)] == [
        list(shapes[i]) for i in range(3)
    ]
    stations = [
        (m.pose.position.x, m.pose.position.y) for _, m in sorted(by_ns['stations'].items())
    ]
    assert stations == [(300.0, 0.0), (800.0, 0.0), (1000.0, 200.0), (1000.0, -300.0)]
    # the latest stamp is A's at c (45 s): A stands at c; B, seen at d at 42.1 s at 25 m/s,
    # is 72.5 m further south on 'right'
    ids = {int(t.sensor_ids[-1]): int(t.track_id) for t in final.tracks}
    got = {i: (m.pose.position.x, m.pose.position.y) for i, m in by_ns['tracks'].items()}
    assert got[ids[IDS[2]]] == pytest.approx((1000.0, 200.0))
    assert got[ids[IDS[3]]] == pytest.approx((1000.0, -300.0 - 25.0 * 2.9))
