"""A /mlkm/handoff reader (the merge's and the shards' QoS) that takes nothing for a while,
run as its own process.

    python stalled_handoff_reader.py <expected> <stall s> <idle timeout s>

Subscribes, prints ``subscribed``, does not spin for ``stall`` seconds (an executor held up
by a loaded machine), then takes messages until it has ``expected`` distinct ``run`` values
or heard nothing for ``idle timeout`` seconds; prints ``received <all> distinct <distinct>``
on its last line.
"""

from __future__ import annotations

import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from mlkm_ros import qos
from road_sensor_msgs.msg import TrackHandoff


def main() -> int:
    expected, stall, idle = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
    rclpy.init()
    node = Node('stalled_handoff_reader')
    runs: list[int] = []
    node.create_subscription(
        TrackHandoff, qos.HANDOFF_TOPIC, lambda m: runs.append(m.run), qos.HANDOFF_READER_QOS
    )
    print('subscribed', flush=True)
    try:
        time.sleep(stall)
        last, seen = time.monotonic(), 0
        while len(set(runs)) < expected and time.monotonic() - last < idle:
            rclpy.spin_once(node, timeout_sec=0.1)
            if len(runs) != seen:
                last, seen = time.monotonic(), len(runs)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        print(f'received {len(runs)} distinct {len(set(runs))}', flush=True)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
