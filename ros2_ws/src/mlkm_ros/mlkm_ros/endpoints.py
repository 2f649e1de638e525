"""Warnings about publishers that cannot reach a subscription, taken from the ROS graph.

rclpy gives every subscription two QoS event handlers by default (an incompatible QoS, an
incompatible type) that log a warning. Each is an entity of the executor's wait set, which
is rebuilt for every message: with a subscription per road sensor they cost more CPU than
the detections' own callbacks at a thousand messages per second. Subscriptions created with
``NO_EVENTS`` have none, and ``PublisherCheck`` gives the same warnings from a periodic look
at the graph (a handful of calls every few seconds, whatever the message rate).
"""

from __future__ import annotations

import time

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSCompatibility, QoSProfile, qos_check_compatible


def no_events() -> SubscriptionEventCallbacks:
    """Event callbacks for ``create_subscription`` that add nothing to the wait set."""
    return SubscriptionEventCallbacks(use_default_callbacks=False)


class PublisherCheck:
    """Warns once per publisher that offers an incompatible QoS or another message type on
    one of the topics checked; ``incompatible`` counts them."""

    def __init__(self, node: Node, type_name: str, qos: QoSProfile, period: float = 2.0) -> None:
        self._node = node
        self._type_name = type_name  # e.g. 'road_sensor_msgs/msg/Detection'
        self._qos = qos
        self._period = period  # [s] between two looks at the graph
        self._due = 0.0
        self._seen: set[tuple[str, bytes]] = set()
        self.incompatible = 0

    def check(self, topics, now: float | None = None) -> None:
        """Look at the publishers of ``topics`` (at most once per period)."""
        now = time.monotonic() if now is None else now
        if now < self._due:
            return
        self._due = now + self._period
        for topic in topics:
            try:
                infos = self._node.get_publishers_info_by_topic(topic)
            except Exception:  # noqa: BLE001 - the context is shutting down
                return
            for info in infos:
                key = (topic, bytes(info.endpoint_gid))
                if key in self._seen:
                    continue
                self._seen.add(key)
                problem = self._problem(info)
                if problem:
                    self.incompatible += 1
                    self._node.get_logger().warning(
                        f'publisher {info.node_namespace.rstrip("/")}/{info.node_name} on '
                        f"'{topic}' {problem}; no messages will be received from it"
                    )

    def _problem(self, info) -> str | None:
        if info.topic_type != self._type_name:
            return f'publishes {info.topic_type}, not {self._type_name}'
        compatibility, reason = qos_check_compatible(info.qos_profile, self._qos)
        if compatibility == QoSCompatibility.ERROR:
            return f'offers an incompatible QoS ({reason.strip()})'
        return None
