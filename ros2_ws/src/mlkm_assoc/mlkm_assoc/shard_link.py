"""The association node as one shard of a long road: its parameters, its region of the
road's layout, and the hand-off topic (publisher and subscriber).

A shard (``shard_count`` > 1, stream mode) takes the stations of its region and the margin
before it (:func:`mlkm_core.shards.regions.split_road`, equal stations per shard), subscribes
only to their detection topics, and trades offers and continuations with its neighbours on
/mlkm/handoff (:mod:`mlkm_assoc.stream_shard`). ``source_namespace`` names where the road's
topics are when the shard runs in a namespace of its own.
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.node import Node

from mlkm_assoc.stream_shard import ShardRole
from mlkm_core.shards.desk import DEFAULT_HORIZON
from mlkm_core.shards.regions import DEFAULT_MARGIN, MAX_SHARDS, split_road
from mlkm_core.types import Layout
from mlkm_ros import qos
from mlkm_ros.handoff_conversions import handoff_from_msg
from mlkm_ros.params import ParamSpec, positive
from mlkm_ros.publishing import ReliablePublisher
from road_sensor_msgs.msg import TrackHandoff

SHARD_PARAMS = ('shard_index', 'shard_count', 'shard_margin', 'handoff_horizon')
SHARD_SPECS = [
    ParamSpec(
        'shard_count',
        1,
        'shards the road is split into (stream mode only); 1: this node takes the whole road [-]',
        1,
        MAX_SHARDS,
        read_only=True,
    ),
    ParamSpec(
        'shard_index',
        0,
        'which shard this node is, 0 the most upstream region [-]',
        0,
        MAX_SHARDS - 1,
        read_only=True,
    ),
    ParamSpec(
        'shard_margin',
        DEFAULT_MARGIN,
        "stations of the upstream shard's region this shard also takes, to link across the "
        'border [-]',
        1,
        100,
        read_only=True,
    ),
    ParamSpec(
        'handoff_horizon',
        DEFAULT_HORIZON,
        "a track's first detection in this shard more than this after its margin detections "
        'starts a new track; an offered track is final this long after nobody took it [s]',
        1e-3,
        1e6,
        check=positive,
        read_only=True,
    ),
    ParamSpec(
        'source_namespace',
        '',
        "namespace of the road's topics (sensor layout, episodes, detections); empty: the "
        "node's own. Shards in namespaces of their own take '/' [-]",
        read_only=True,
    ),
]


def source_topic(node: Node, namespace: str, topic: str) -> str:
    """``topic`` (relative) resolved in ``namespace``, or in the node's own when empty."""
    if not namespace:
        return node.resolve_topic_name(topic)
    return node.resolve_topic_name(namespace.rstrip('/') + '/' + topic)


def handoff_publisher(node: Node) -> ReliablePublisher:
    """The node's /mlkm/handoff publisher: KEEP_LAST for late joiners, flow-controlled below
    that depth so that a reader that falls behind loses nothing (``qos.HANDOFF_READER_QOS``)."""
    return ReliablePublisher(
        node.create_publisher(TrackHandoff, qos.HANDOFF_TOPIC, qos.HANDOFF_QOS),
        node.context,
        window=qos.HANDOFF_FLOW_WINDOW,
    )


class ShardLink:
    """The node's shard side: the region of each layout and the hand-off topic."""

    def __init__(self, node: Node, index: int, count: int, margin: int, horizon: float) -> None:
        if index >= count:
            raise ValueError(f'shard_index {index} is not below shard_count {count}')
        self.index, self.count = index, count
        self.margin, self.horizon = margin, horizon
        self.role: ShardRole | None = None
        self._node = node
        self._take: Callable[[list, float], None] | None = None
        self._pub = handoff_publisher(node)
        self._sub = node.create_subscription(
            TrackHandoff, qos.HANDOFF_TOPIC, self._on_handoff, qos.HANDOFF_READER_QOS
        )
        self._upstream_run = 0
        self._early: list[tuple[list, float]] = []  # offers before the tracker had a road
        self.received = 0
        self.refused = 0

    def region(self, layout: Layout, lane_counts):
        """(the region's layout, its lane counts, the role)."""
        regions = split_road(layout.n_sensors, self.count, self.margin)
        region = regions[self.index]
        self.role = ShardRole.of(region, layout, self.horizon)
        lanes = None if lane_counts is None else tuple(lane_counts[s] for s in region.stations)
        return region.layout(layout), lanes, self.role

    def connect(self, take: Callable[[list, float], None]) -> None:
        """Give offers of the upstream shard to ``take(offers, upstream_until)`` (those that
        came before too)."""
        self._take = take
        early, self._early = self._early, []
        for offers, until in early:
            take(offers, until)

    def publish(self, data: bytes) -> None:
        if self._node.context.ok():
            self._pub.publish(data)

    def _on_handoff(self, msg: TrackHandoff) -> None:
        if msg.shard + 1 != self.index:
            return
        try:
            h = handoff_from_msg(msg)
        except ValueError as exc:
            self.refused += 1
            self._node.get_logger().error(
                f'hand-off of shard {msg.shard} refused: {exc}', throttle_duration_sec=2.0
            )
            return
        if h.run < self._upstream_run:
            return  # a message of the upstream shard's run before its restart
        self._upstream_run = h.run
        self.received += 1
        if self._take is None:
            self._early.append((h.offered_detections(), h.committed_until))
        else:
            self._take(h.offered_detections(), h.committed_until)

    def diagnostics(self, values: dict) -> None:
        values['shard'] = f'{self.index}/{self.count}'
        values['shard.handoffs_received'] = self.received
        values['shard.handoffs_refused'] = self.refused
        if self.role is not None:
            values['shard.margin_stations'] = len(self.role.margin_ids)
