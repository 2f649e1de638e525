"""The association node's /mlkm/markers (see :mod:`mlkm_ros.markers` for what is drawn).

The node hands over what it sees: the layout, every detection (cheap: a deque append on the
executor thread), and every TrackArray it publishes (the serialized bytes, from its
publisher threads). A timer at ``markers_rate`` decodes the arrays that came in, places each
track along the road and publishes one MarkerArray, only when something changed and somebody
subscribes.

Time is stamp time, never wall time: "now" is the graph's latest detection stamp, so a bag
replayed at any rate places the tracks the same. A track sits at its last station plus its
last speed times the time since its last detection, clamped to the next station (or the
road's end). In episodes mode the tracks are those of the latest TrackArray (the episode's
association so far); a FINAL track that reached its clamp has left and is not drawn. In stream
mode the arrays carry the tracks that changed: they are merged by id, a run's tracks end when
another run begins, a FINAL track is dropped once it reached its clamp, and a track whose
latest detection is stamped before ``committed_until`` is drawn as committed, else as
revisable. On a road network whose links have shapes the same holds in the network's plane
(:mod:`mlkm_ros.network_markers`): a track sits on the link of its latest detection.

Where ``tf2_msgs`` is importable (a ROS 2 install), /tf_static also gets the identity
transform ``markers_parent_frame`` -> ``road``; the wheels do not carry tf2_msgs, and tools
that display frame ``road`` itself need no transform.
"""

from __future__ import annotations

import threading
from collections import deque

import numpy as np
from rclpy.node import Node
from visualization_msgs.msg import MarkerArray

from mlkm_assoc.validation import POSITION_TOLERANCE
from mlkm_core.bounds import Bounds
from mlkm_core.network_assoc.stations import NetworkStations
from mlkm_core.types import Layout
from mlkm_ros import qos
from mlkm_ros.markers import FRAME, Scene, TrackView, build_markers, clear_all, next_station
from mlkm_ros.markers import track_position as place
from mlkm_ros.network_markers import NetworkGeometry, build_network_markers, network_geometry
from mlkm_ros.track_summary import Passage, Summary, summarize
from road_sensor_msgs.msg import Track, TrackArray

#: Recent detections drawn per station [-].
DETECTIONS_SHOWN = 8
#: Track arrays held between two marker publications; beyond, the oldest are dropped [-].
MAX_PENDING = 10_000
NS_PER_S = 1_000_000_000


def track_x(p: Passage, now_ns: int, positions, road_length: float) -> tuple[float, float]:
    """(where the track is [m], the position it is clamped to [m]) at stamp ``now_ns``."""
    limit = next_station(positions, p.position, road_length)
    x = place(p.position, p.stamp_ns / NS_PER_S, p.velocity, now_ns / NS_PER_S, limit)
    return x, limit


class RoadMarkers:
    """Builds and publishes the node's /mlkm/markers."""

    def __init__(self, node: Node, enabled: bool, rate: float, parent_frame: str) -> None:
        self.enabled = enabled
        self._node = node
        self._lock = threading.Lock()
        self._pending: deque[bytes] = deque(maxlen=MAX_PENDING)
        self._layout: Layout | None = None
        self._geometry: NetworkGeometry | None = None  # a network's, where it is drawn
        self._index: dict[int, int] = {}  # sensor id -> station index
        self._recent: list[deque[tuple[int, float]]] = []
        self._now_ns = -1  # the graph's latest detection stamp [ns]
        self._changed = False
        self._stream = False
        self._run = 0
        self._committed_until_ns = 0
        self._status = ''
        self._passages: dict[int, Passage] = {}
        self._shown = False  # the last array published was a picture, not a clear
        self.published = 0
        self._pub = node.create_publisher(MarkerArray, qos.MARKERS_TOPIC, qos.MARKERS_QOS)
        self._timer = node.create_timer(1.0 / rate, self.publish)
        self._tf_pub = _publish_static_transform(node, parent_frame)

    # --- inputs ---------------------------------------------------------------------------
    def layout(self, layout: Layout) -> None:
        """A new (valid) layout. A road network is drawn where its links have shapes
        (``mlkm_ros.network_markers``); one without them has nothing to place and is not
        drawn (logged once)."""
        geometry = None
        if isinstance(layout, NetworkStations):
            geometry = network_geometry(layout.network)
            if geometry is None:
                self._node.get_logger().info(
                    '/mlkm/markers: the network layout carries no link shapes; nothing drawn'
                )
                self._layout, self._geometry, self._index, self._recent = None, None, {}, []
                self._passages.clear()
                if self._shown:
                    self._pub.publish(MarkerArray(markers=[clear_all()]))
                    self._shown = False
                return
        old = self._layout
        if (
            old is not None
            and type(old) is type(layout)
            and old.road_length == layout.road_length
            and old.names == layout.names
            and np.array_equal(old.positions, layout.positions)
            and np.array_equal(old.sensor_ids, layout.sensor_ids)
            and getattr(old, 'network', None) == getattr(layout, 'network', None)
        ):
            return  # the same road again (a source restarted): its recent detections stay
        # another road: its stamps, detections and tracks start afresh
        self._layout, self._geometry = layout, geometry
        self._index = {int(s): i for i, s in enumerate(layout.sensor_ids)}
        self._recent = [deque(maxlen=DETECTIONS_SHOWN) for _ in self._index]
        self._now_ns = -1
        self._passages.clear()
        self._changed = True

    def detection(
        self,
        sensor_id: int,
        stamp_ns: int,
        position: float,
        velocity: float,
        lane: int,
        bounds: Bounds,
    ) -> None:
        """A detection as received (executor thread). Checked as the node checks it (a known
        sensor at its position, speed and stamp within ``bounds``), so that a refused one
        does not move the picture."""
        i = self._index.get(sensor_id)
        if i is None or bounds.refuse(stamp_ns / NS_PER_S, velocity) is not None:
            return
        if not abs(position - self._layout.positions[i]) <= POSITION_TOLERANCE:
            return
        self._recent[i].append((lane, velocity))
        if stamp_ns > self._now_ns:
            self._now_ns = stamp_ns
        self._changed = True

    def tracks(self, data: bytes) -> None:
        """A serialized TrackArray the node published (any thread)."""
        if self.enabled:
            with self._lock:
                self._pending.append(data)

    # --- publication (timer) --------------------------------------------------------------
    def publish(self) -> None:
        """The timer: one MarkerArray when something changed. A failure here is logged and
        never reaches the association (the markers start again from the next input)."""
        try:
            self._publish()
        except Exception as exc:  # noqa: BLE001 - a picture is not worth the node
            self._passages.clear()
            self._node.get_logger().error(
                f'/mlkm/markers not published: {exc}', throttle_duration_sec=10.0
            )

    def _publish(self) -> None:
        with self._lock:
            pending = list(self._pending)
            self._pending.clear()
        if not self.enabled:
            if self._shown:  # switched off: clear the displays
                self._pub.publish(MarkerArray(markers=[clear_all()]))
                self._shown = False
                self._passages.clear()
            return
        if self._layout is None:
            return
        if self._pub.get_subscription_count() == 0:
            # nobody looks: keep only the latest array, for a subscriber to start from
            self._passages.clear()
            with self._lock:
                self._pending.extendleft(pending[-1:])
            return
        for data in pending:
            self._take(summarize(data))
            self._changed = True
        if not self._changed:
            return
        self._changed = False
        if self._geometry is not None:
            self._pub.publish(build_network_markers(self._geometry, *self.network_scene()))
        else:
            self._pub.publish(build_markers(self.scene()))
        self._shown = True
        self.published += 1

    def _take(self, msg: Summary) -> None:
        if msg.mode == TrackArray.MODE_STREAM:
            if not self._stream or msg.run != self._run:
                self._passages.clear()  # a new run: the tracks of the old one have ended
            self._stream, self._run = True, msg.run
            self._committed_until_ns = msg.committed_until_ns
            for track_id, p in msg.tracks:
                if p is None:
                    self._passages.pop(track_id, None)
                else:
                    self._passages[track_id] = p
            self._status = 'stream'
            if self._committed_until_ns > 0:
                self._status += f', committed until {self._committed_until_ns / NS_PER_S:.1f} s'
            return
        self._stream = False
        self._passages = {track_id: p for track_id, p in msg.tracks if p is not None}
        self._status = (
            f'episode {msg.episode_id}, {msg.segments_done}/{msg.segments_total} segments'
            + (', final' if msg.final else '')
        )

    def scene(self) -> Scene:
        """What the next MarkerArray shows (FINAL tracks that have left are dropped)."""
        layout = self._layout
        positions = layout.positions.tolist()

        def along(p: Passage) -> tuple[float, float, bool]:
            x, limit = track_x(p, self._now_ns, positions, layout.road_length)
            return x, 0.0, x >= limit

        return Scene(
            stamp_ns=max(self._now_ns, 0),
            road_length=float(layout.road_length),
            positions=positions,
            names=list(layout.names),
            detections=[list(d) for d in self._recent],
            tracks=self._views(along),
            status=self._status,
        )

    def network_scene(self) -> tuple[int, list[TrackView], str]:
        """(stamp [ns], tracks, status) of the next MarkerArray of a network: each track on
        the link of its latest detection (FINAL tracks that have left are dropped)."""
        g, now = self._geometry, self._now_ns / NS_PER_S

        def on_link(p: Passage) -> tuple[float, float, bool] | None:
            station = self._index.get(p.sensor_id)
            if station is None:
                return None
            return g.place(station, p.stamp_ns / NS_PER_S, p.velocity, now)

        return max(self._now_ns, 0), self._views(on_link), self._status

    def _views(self, place) -> list[TrackView]:
        """Each track where ``place`` puts it ((x [m], y [m], at its clamp), or None: not
        drawn); a FINAL track at its clamp has left: not drawn, and in stream mode dropped."""
        views = []
        for track_id, p in list(self._passages.items()):
            where = place(p)
            if where is None:
                continue
            x, y, reached = where
            if p.status == Track.STATUS_FINAL and reached:
                if self._stream:
                    del self._passages[track_id]
                continue
            committed = p.stamp_ns < self._committed_until_ns if self._stream else None
            views.append(TrackView(int(track_id), x, committed, y))
        return views


def _publish_static_transform(node: Node, parent_frame: str):
    """The identity transform ``parent_frame`` -> ``road`` on /tf_static, where tf2_msgs is
    installed and ``parent_frame`` is not empty; the publisher, or None."""
    if not parent_frame:
        return None
    try:
        from geometry_msgs.msg import TransformStamped
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    pub = node.create_publisher(TFMessage, qos.TF_STATIC_TOPIC, qos.TF_STATIC_QOS)
    t = TransformStamped()
    t.header.stamp = node.get_clock().now().to_msg()
    t.header.frame_id = parent_frame
    t.child_frame_id = FRAME
    t.transform.rotation.w = 1.0
    pub.publish(TFMessage(transforms=[t]))
    return pub
