"""The paper's preprocessing: back-projection of passage times to a reference sensor.

A detection at position R_n with time t and speed v is mapped to the time at which the
target would have passed the reference position R_ref had it kept the speed v::

    t' = t - (R_n - R_ref) / v          (back_project)
    t  = t' + (R_n - R_ref) / v         (forward_project, the inverse)

The reference is the first sensor of the road (the paper's S_1) unless given.
"""

from __future__ import annotations

import numpy as np

from mlkm_core.types import Detections, Layout


def back_project(
    stamp: np.ndarray, velocity: np.ndarray, position: np.ndarray, ref_position: float
) -> np.ndarray:
    """t' = t - (R_n - R_ref) / v, elementwise."""
    return np.asarray(stamp, float) - (np.asarray(position, float) - ref_position) / np.asarray(
        velocity, float
    )


def forward_project(
    stamp_ref: np.ndarray, velocity: np.ndarray, position: np.ndarray, ref_position: float
) -> np.ndarray:
    """Inverse of ``back_project``: t = t' + (R_n - R_ref) / v."""
    return np.asarray(stamp_ref, float) + (np.asarray(position, float) - ref_position) / (
        np.asarray(velocity, float)
    )


def preprocess(
    layout: Layout, detections: Detections, ref_position: float | None = None
) -> np.ndarray:
    """Back-projected stamps of ``detections`` to ``ref_position`` (default: first sensor)."""
    ref = float(layout.positions[0]) if ref_position is None else float(ref_position)
    return back_project(
        detections.stamp, detections.velocity, layout.positions[detections.sensor_index], ref
    )
