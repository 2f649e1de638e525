"""A deliberately slow /road/ground_truth subscriber (contract QoS), run as its own process.

    python slow_truth_subscriber.py <expected> <delay s> <stall s> <idle timeout s>

Sleeps ``delay`` seconds in every callback and ``stall`` seconds in every 500th (a subscriber
that stops now and then, as a loaded machine makes any subscriber do), so that a publisher at
full speed outruns it.
Exits when it has ``expected`` distinct messages or heard nothing for ``idle timeout`` seconds;
prints ``received <all> distinct <distinct> negative_stamps <n>`` on its last line.
"""

from __future__ import annotations

import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from mlkm_ros import qos
from road_sensor_msgs.msg import GroundTruth


class SlowTruthSubscriber(Node):
    def __init__(self, delay: float, stall: float) -> None:
        super().__init__('slow_truth_subscriber')
        self._delay: float = delay
        self._stall: float = stall
        self.received: int = 0
        self.negative: int = 0
        self.keys: set[tuple[int, int, int, int]] = set()
        self.last: float = time.monotonic()
        self.create_subscription(
            GroundTruth, qos.GROUND_TRUTH_TOPIC, self._on_truth, qos.GROUND_TRUTH_QOS
        )

    def _on_truth(self, msg: GroundTruth) -> None:
        self.received += 1
        stamp = msg.header.stamp
        self.negative += stamp.sec < 0
        self.keys.add((msg.episode_id, msg.sensor_id, stamp.sec, stamp.nanosec))
        self.last = time.monotonic()
        time.sleep(self._stall if self.received % 500 == 0 else self._delay)


def main() -> int:
    expected, delay, stall, idle = int(sys.argv[1]), *map(float, sys.argv[2:5])
    rclpy.init()
    node = SlowTruthSubscriber(delay, stall)
    print('subscribed', flush=True)
    try:
        while len(node.keys) < expected and time.monotonic() - node.last < idle:
            rclpy.spin_once(node, timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        print(
            f'received {node.received} distinct {len(node.keys)} negative_stamps {node.negative}',
            flush=True,
        )
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
