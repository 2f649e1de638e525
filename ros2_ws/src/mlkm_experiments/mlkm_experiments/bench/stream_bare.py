"""The bare rclpy subscriber of the stream part's throughput measurement:
``python -m mlkm_experiments.bench.stream_bare`` subscribes to every detection topic of the
layout, counts, and prints ``{"received", "ingest_rate"}`` as JSON once nothing arrived for 3 s
after the first detection (a module of its own: the bench package does not import it)."""

from __future__ import annotations

import json
import sys
import time


def bare_subscriber(idle: float = 3.0) -> int:
    """Subscribe to every detection topic of the layout and count; print JSON once nothing
    arrived for ``idle`` seconds after the first detection."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.node import Node

    from mlkm_ros import qos
    from road_sensor_msgs.msg import Detection, SensorLayout

    class Bare(Node):
        def __init__(self) -> None:
            super().__init__('bare_subscriber')
            self.count, self.first, self.last = 0, 0.0, 0.0
            self.subs = []
            self.create_subscription(
                SensorLayout, qos.LAYOUT_TOPIC, self.on_layout, qos.LAYOUT_QOS
            )
            self.create_timer(0.5, self.check)

        def on_layout(self, msg: SensorLayout) -> None:
            if not self.subs:
                self.subs = [
                    self.create_subscription(
                        Detection, qos.detections_topic(n), self.on_detection, qos.DETECTIONS_QOS
                    )
                    for n in msg.sensor_names
                ]

        def on_detection(self, msg: Detection) -> None:
            now = time.monotonic()
            if self.count == 0:
                self.first = now
            self.last = now
            self.count += 1

        def check(self) -> None:
            if self.count and time.monotonic() - self.last > idle:
                raise SystemExit(0)

    rclpy.init()
    node = Bare()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException, SystemExit):
        pass
    finally:
        rate = (node.count - 1) / (node.last - node.first) if node.last > node.first else 0.0
        print(json.dumps({'received': node.count, 'ingest_rate': rate}), flush=True)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(bare_subscriber())
