"""A test node of the graph tests that replay a log: it receives the scores, the layout and
the episode infos the graph publishes (its own executor, spun by the test)."""

from __future__ import annotations

from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from mlkm_ros import qos
from road_sensor_msgs.msg import AssociationScore, EpisodeInfo, SensorLayout


class Listener:
    """Receives scores (by episode), the layout and the episode infos."""

    def __init__(self, context, name: str = 'log_test_listener') -> None:
        self.node = Node(name, context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.scores: dict[int, AssociationScore] = {}
        self.layout: list[SensorLayout] = []
        self.infos: list[EpisodeInfo] = []
        sub = self.node.create_subscription
        sub(AssociationScore, qos.SCORE_TOPIC, self._on_score, qos.SCORE_QOS)
        sub(SensorLayout, qos.LAYOUT_TOPIC, self.layout.append, qos.LAYOUT_QOS)
        sub(EpisodeInfo, qos.EPISODE_TOPIC, self.infos.append, qos.EPISODE_QOS)

    def _on_score(self, msg: AssociationScore) -> None:
        self.scores[msg.episode_id] = msg

    def ended(self) -> bool:
        """Whether an EpisodeInfo ENDED arrived."""
        return any(i.status == EpisodeInfo.STATUS_ENDED for i in self.infos)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
