"""Stamps: ROS times <-> integer nanoseconds <-> seconds, and message headers.

Times travel as ``builtin_interfaces/Time`` and are handled as integer nanoseconds (the join
key of detections, tracks and ground truth); the core gets seconds as float64 via
:func:`ns_to_seconds`. :mod:`mlkm_ros.conversions` re-exports every name.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Time
from std_msgs.msg import Header

NS_PER_S = 1_000_000_000
FRAME_ID = 'road'


def seconds_to_ns(seconds: float) -> int:
    """A time in seconds (float) -> integer nanoseconds, rounded to the nearest ns."""
    return int(round(float(seconds) * NS_PER_S))


def seconds_to_ns_array(seconds: np.ndarray) -> np.ndarray:
    return np.rint(np.asarray(seconds, dtype=float) * NS_PER_S).astype(np.int64)


def ns_to_seconds(ns: np.ndarray | Sequence[int]) -> np.ndarray:
    """Integer nanoseconds -> seconds as float64 (what the core works with)."""
    return np.asarray(ns, dtype=np.int64) / NS_PER_S


def ns_to_time(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def time_to_ns(stamp: Time) -> int:
    return stamp.sec * NS_PER_S + stamp.nanosec


def header(stamp_ns: int) -> Header:
    return Header(stamp=ns_to_time(stamp_ns), frame_id=FRAME_ID)
