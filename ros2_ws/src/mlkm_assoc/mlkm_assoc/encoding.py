"""Solver results -> serialized TrackArray messages (the ROS side of the solver process).

:mod:`mlkm_assoc.solver` stays ROS-free; the solver process calls :func:`encode` on each
result so that the node's process only hands finished bytes to the middleware.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from rclpy.serialization import serialize_message

from mlkm_assoc.solver import Result
from mlkm_core.network_assoc.stations import NetworkStations
from mlkm_core.types import UNASSIGNED
from mlkm_ros.conversions import tracks_to_msg


@dataclass(frozen=True)
class Update:
    """A result ready to publish: the serialized TrackArray and what the node logs."""

    data: bytes  # CDR of road_sensor_msgs/msg/TrackArray
    episode_id: int
    final: bool
    detections: int
    tracks: int
    unassigned: int
    solve_time: float  # [s]
    completed_at: float  # monotonic time the segment was complete
    forced: bool
    error: str | None
    started_at: float  # monotonic time the solver took the job
    missing: int = 0  # detections ENDED announced that this node never received [-]


def encode(result: Result) -> Update:
    """Build and serialize the TrackArray of ``result``."""
    layout = result.layout
    msg = tracks_to_msg(
        episode_id=result.episode_id,
        method=result.method,
        final=result.final,
        segments_done=result.segments_done,
        segments_total=result.segments_total,
        sensor_ids=layout.sensor_ids[result.sensor_index],
        stamps_ns=result.stamps_ns,
        velocities=result.velocities,
        positions=layout.positions[result.sensor_index],
        labels=result.labels,
        solve_time=result.solve_time,
        stamp_ns=time.time_ns(),
        lanes=result.lanes,
        lengths=result.lengths,
        retired=result.retired,
        by_stamp=isinstance(layout, NetworkStations),  # positions lie on different links
    )
    labels = result.labels
    return Update(
        data=serialize_message(msg),
        episode_id=result.episode_id,
        final=result.final,
        detections=int(labels.size),
        tracks=int(np.unique(labels[labels != UNASSIGNED]).size),
        unassigned=int((labels == UNASSIGNED).sum()),
        solve_time=result.solve_time,
        completed_at=result.completed_at,
        forced=result.forced,
        error=result.error,
        started_at=result.started_at,
        missing=result.missing,
    )
