"""Plain data types shared by the simulator, the associators, the metrics and the adapters.

Nothing here knows about ROS. A road has sensors ordered by position; detections are a
struct of arrays, one element per passage, with the sensor given as an index into the
layout (``sensor_index``), never as a raw id.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Label of a detection that no track took, and ``target`` of a false alarm.
UNASSIGNED = -1
FALSE_ALARM = -1
#: ``Detections.lane`` of a detection whose lane is not known.
UNKNOWN_LANE = -1


def duplicate_key(sensor_id: int, lane: int, stamp: float, velocity: float) -> tuple:
    """The identity of one report: two detections with equal keys are the same report
    received twice (the second is a duplicate).

    A report is (sensor, lane, stamp) where the lane is known. Where it is not
    (``UNKNOWN_LANE``), the velocity is part of the key, so that two vehicles crossing one
    station at the same instant in different lanes, at different speeds, are both kept.
    ``stamp`` is compared exactly, in whatever unit the caller uses (ns in the node, s in a
    CSV). The node and the offline CLI both decide duplicates with this one function."""
    if lane == UNKNOWN_LANE:
        return (sensor_id, lane, stamp, velocity)
    return (sensor_id, lane, stamp, 0.0)


def default_sensor_name(sensor_id: int) -> str:
    """The name of a sensor (station) that has none: its detection topic's token."""
    return f'sensor_{sensor_id}'


@dataclass(frozen=True)
class Layout:
    """A road of length ``road_length`` [m] with sensors at strictly increasing positions.

    The road is [0, road_length]: a station may stand at its origin (0) or at its end."""

    road_length: float
    positions: np.ndarray  # [m], shape (n_sensors,), strictly increasing, on [0, D]
    sensor_ids: np.ndarray = field(default=None)  # uint ids, shape (n_sensors,)
    names: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions, dtype=float)
        if pos.ndim != 1 or pos.size == 0:
            raise ValueError('a layout needs at least one sensor position')
        if not np.all(np.isfinite(pos)):
            raise ValueError('sensor positions must be finite')
        self._check_positions(pos)
        ids = (
            np.arange(pos.size, dtype=np.int64)
            if self.sensor_ids is None
            else np.asarray(self.sensor_ids, dtype=np.int64)
        )
        if ids.shape != pos.shape or np.unique(ids).size != ids.size or np.any(ids < 0):
            raise ValueError('sensor ids must be unique, non-negative, one per position')
        names = tuple(self.names) or tuple(default_sensor_name(int(i)) for i in ids)
        if len(names) != pos.size or len(set(names)) != len(names):
            raise ValueError('sensor names must be unique, one per position')
        object.__setattr__(self, 'positions', pos)
        object.__setattr__(self, 'sensor_ids', ids)
        object.__setattr__(self, 'names', names)

    def _check_positions(self, pos: np.ndarray) -> None:
        """The road's rule: strictly increasing, on [0, road_length]."""
        if np.any(np.diff(pos) <= 0):
            raise ValueError('sensor positions must be unique and strictly increasing')
        if not (self.road_length > 0 and pos[0] >= 0 and pos[-1] <= self.road_length):
            raise ValueError('sensor positions must lie on the road [0, road_length]')

    @property
    def n_sensors(self) -> int:
        return int(self.positions.size)

    def index_of(self, sensor_ids: np.ndarray | int) -> np.ndarray:
        """Map sensor ids to layout indices; raises KeyError for an unknown id."""
        lookup = {int(s): i for i, s in enumerate(self.sensor_ids)}
        ids = np.atleast_1d(np.asarray(sensor_ids, dtype=np.int64))
        try:
            return np.array([lookup[int(s)] for s in ids], dtype=np.int64)
        except KeyError as exc:
            raise KeyError(f'unknown sensor id {exc.args[0]}') from None


@dataclass
class Detections:
    """Detections as parallel arrays; ``target`` is ground truth and may be absent.

    ``lane`` (index from the right, 0 = rightmost, ``UNKNOWN_LANE`` = -1) and ``length``
    (vehicle length [m], NaN = unknown) are optional per-detection measurements that
    sensors reporting them (loop detectors) fill in; assignment, multiframe and mlkm_robust use
    them in their link costs (the cues of ``mlkm_core.model``).
    """

    sensor_index: np.ndarray  # int, index into Layout.positions
    stamp: np.ndarray  # passage time [s]
    velocity: np.ndarray  # measured speed [m/s]
    target: np.ndarray | None = None  # true target id, FALSE_ALARM (-1) for clutter
    lane: np.ndarray | None = None  # lane index from the right, -1 = unknown
    length: np.ndarray | None = None  # measured vehicle length [m], NaN = unknown

    def __post_init__(self) -> None:
        self.sensor_index = np.asarray(self.sensor_index, dtype=np.int64)
        self.stamp = np.asarray(self.stamp, dtype=float)
        self.velocity = np.asarray(self.velocity, dtype=float)
        n = self.sensor_index.size
        if self.stamp.shape != (n,) or self.velocity.shape != (n,):
            raise ValueError('sensor_index, stamp and velocity must be 1-D of equal length')
        if self.target is not None:
            self.target = np.asarray(self.target, dtype=np.int64)
            if self.target.shape != (n,):
                raise ValueError('target must be 1-D with one entry per detection')
        if self.lane is not None:
            self.lane = np.asarray(self.lane, dtype=np.int64)
            if self.lane.shape != (n,):
                raise ValueError('lane must be 1-D with one entry per detection')
            if np.any(self.lane < UNKNOWN_LANE):
                raise ValueError('lane must be >= 0, or -1 for unknown')
        if self.length is not None:
            self.length = np.asarray(self.length, dtype=float)
            if self.length.shape != (n,):
                raise ValueError('length must be 1-D with one entry per detection')

    def __len__(self) -> int:
        return int(self.sensor_index.size)

    def subset(self, mask_or_index: np.ndarray) -> Detections:
        return Detections(
            self.sensor_index[mask_or_index],
            self.stamp[mask_or_index],
            self.velocity[mask_or_index],
            None if self.target is None else self.target[mask_or_index],
            None if self.lane is None else self.lane[mask_or_index],
            None if self.length is None else self.length[mask_or_index],
        )

    @staticmethod
    def concatenate(parts: list[Detections]) -> Detections:
        """Join detections; a lane or length column present in any part is kept, with the
        unknown value (-1, NaN) for the parts that lack it."""
        if not parts:
            return Detections(np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
        with_truth = all(p.target is not None for p in parts)
        lane = None
        if any(p.lane is not None for p in parts):
            lane = np.concatenate(
                [
                    np.full(len(p), UNKNOWN_LANE, np.int64) if p.lane is None else p.lane
                    for p in parts
                ]
            )
        length = None
        if any(p.length is not None for p in parts):
            length = np.concatenate(
                [np.full(len(p), np.nan) if p.length is None else p.length for p in parts]
            )
        return Detections(
            np.concatenate([p.sensor_index for p in parts]),
            np.concatenate([p.stamp for p in parts]),
            np.concatenate([p.velocity for p in parts]),
            np.concatenate([p.target for p in parts]) if with_truth else None,
            lane,
            length,
        )


@dataclass
class Dataset:
    """One episode: a layout, its detections with truth, and the number of true targets."""

    layout: Layout
    detections: Detections
    n_targets: int


def segments(n_sensors: int, segment_size: int) -> list[np.ndarray]:
    """Split sensor indices 0..n_sensors-1 into E = ceil(N_S / K) consecutive segments.

    The last segment is shorter when K does not divide N_S (the paper's Layer 1).
    """
    if segment_size < 1:
        raise ValueError('segment_size must be at least 1')
    return [
        np.arange(s, min(s + segment_size, n_sensors)) for s in range(0, n_sensors, segment_size)
    ]


def link_pairs(d: Detections, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive detections (by sensor) of each track: (earlier, later) indices."""
    valid = np.flatnonzero(labels >= 0)
    order = valid[np.lexsort((d.sensor_index[valid], labels[valid]))]
    same = labels[order[1:]] == labels[order[:-1]]
    return order[:-1][same], order[1:][same]
