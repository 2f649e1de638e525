"""The static transform parent -> road is built and published once where tf2_msgs can be
imported; without it (the PyPI wheels) or with no parent frame, nothing is published. The
node is a stand-in: this checks the message, tests/node checks it on a ROS 2 install."""

from __future__ import annotations

import sys
import types

from mlkm_assoc.association_markers import _publish_static_transform
from mlkm_ros import qos


class _Publisher:
    def __init__(self) -> None:
        self.sent: list = []

    def publish(self, msg) -> None:
        self.sent.append(msg)


class _Node:
    def __init__(self) -> None:
        self.publishers: list[tuple] = []

    def create_publisher(self, kind, topic, profile):
        pub = _Publisher()
        self.publishers.append((kind, topic, profile, pub))
        return pub

    def get_clock(self):
        from rclpy.clock import Clock

        return Clock()


class _TFMessage:
    def __init__(self, transforms) -> None:
        self.transforms = transforms


def test_identity_transform_when_tf2_msgs_imports(monkeypatch) -> None:
    package = types.ModuleType('tf2_msgs')
    msg = types.ModuleType('tf2_msgs.msg')
    msg.TFMessage = _TFMessage
    monkeypatch.setitem(sys.modules, 'tf2_msgs', package)
    monkeypatch.setitem(sys.modules, 'tf2_msgs.msg', msg)
    node = _Node()
    assert _publish_static_transform(node, 'map') is not None
    ((kind, topic, profile, pub),) = node.publishers
    assert (kind, topic, profile) == (_TFMessage, '/tf_static', qos.TF_STATIC_QOS)
    ((t,),) = [m.transforms for m in pub.sent]
    assert (t.header.frame_id, t.child_frame_id) == ('map', 'road')
    r, p = t.transform.rotation, t.transform.translation
    assert (r.x, r.y, r.z, r.w, p.x, p.y, p.z) == (0, 0, 0, 1, 0, 0, 0)


def test_nothing_without_tf2_msgs_or_parent(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, 'tf2_msgs', None)  # import fails
    node = _Node()
    assert _publish_static_transform(node, 'map') is None
    assert _publish_static_transform(node, '') is None
    assert node.publishers == []
