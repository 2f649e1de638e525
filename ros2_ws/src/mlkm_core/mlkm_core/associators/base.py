"""The one associator interface that MLKM and every baseline implement.

An associator turns anonymous detections into labels: ``labels[i]`` is the track of
detection ``i`` (an int >= 0) or ``UNASSIGNED`` (-1). Track numbers are arbitrary; the
metrics map them to targets.

Live use goes through a session: the association node feeds one completed road segment
at a time (sensor indices ascending, segment after segment) and gets the labels of every
detection fed so far. Batch and incremental must agree: ``associate`` over all detections
equals feeding the segments one by one, and the tests check it for every method.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from mlkm_core.registry import Registry
from mlkm_core.types import Detections, Layout, segments

if TYPE_CHECKING:
    from mlkm_core.model.motion import MotionParams


@dataclass(frozen=True)
class AssociatorConfig:
    """Settings shared by all associators; each one reads the fields it needs."""

    segment_size: int = 5  # K, sensors per segment (MLKM layer 1 and the live buffering)
    seed: int = 0  # random_state of K-means / K-means++ / the DNN
    # multiframe: most candidate exchanges its local search scores per starting point (a
    # deterministic work budget; the search keeps the best labelling found within it)
    search_budget: int = 500_000
    # an open road: positions [m] along the road where vehicles can enter (on-ramps) and leave
    # (off-ramps) between sensors; a track that starts after an entry or ends before an exit
    # is not charged for the sensors it could not pass (multiframe's likelihood, and the
    # joining of track fragments of the three tracking methods)
    entries: tuple[float, ...] = ()
    exits: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if self.search_budget < 0:
            raise ValueError(f'search_budget must be >= 0, got {self.search_budget}')
        for name in ('entries', 'exits'):
            values = tuple(float(x) for x in getattr(self, name))
            if not all(math.isfinite(x) for x in values):
                raise ValueError(f'{name} must be finite positions along the road, got {values}')
            object.__setattr__(self, name, values)


class DegradedResultWarning(UserWarning):
    """An associator returned a valid but weaker result (a fallback or a cut-short search)."""


def canonical_order(detections: Detections) -> np.ndarray:
    """Permutation sorting detections by (sensor_index, stamp, velocity).

    Every associator reads detections in this order, so its result does not depend on the
    order in which they were given (batch and incremental feed the same detections in
    different orders).
    """
    return np.lexsort((detections.velocity, detections.stamp, detections.sensor_index))


class Session:
    """Incremental association over consecutive segments of one episode.

    The default implementation re-runs the batch ``associate`` on everything fed so far,
    which is exact (batch == incremental) for any method. Methods that can do better (MLKM
    solves layers 1 and 2 per segment and matches only the new one) override it.
    """

    def __init__(self, associator: Associator, layout: Layout, n_targets: int) -> None:
        self._associator = associator
        self._layout = layout
        self._n_targets = n_targets
        self._parts: list[Detections] = []

    @property
    def detections(self) -> Detections:
        """Every detection fed so far, in the order fed; labels follow this order."""
        return Detections.concatenate(self._parts)

    def add_segment(self, detections: Detections) -> np.ndarray:
        """Feed the detections of the next completed segment; return labels of all so far."""
        self._parts.append(detections)
        return self._associator.associate(self._layout, self.detections, self._n_targets)


class Associator(ABC):
    """Base class: a name, a config, a batch ``associate`` and an incremental ``session``."""

    name: ClassVar[str]
    #: ``associate`` takes ``motion=``: motion parameters calibrated elsewhere, bound to its
    #: input in canonical order (``calibration.CarriedModel.bind``), used instead of
    #: calibrating on the input (the stream tracker calibrates once every few windows)
    calibrates: ClassVar[bool] = False

    def __init__(self, config: AssociatorConfig | None = None) -> None:
        self.config = config or AssociatorConfig()

    @abstractmethod
    def associate(self, layout: Layout, detections: Detections, n_targets: int) -> np.ndarray:
        """Return one label per detection: a track number >= 0 or UNASSIGNED (-1)."""

    def settled(
        self,
        layout: Layout,
        d: Detections,
        params: MotionParams,
        evidence: tuple[float, float] | None,
    ) -> tuple[MotionParams, tuple[float, float] | None]:
        """What this method decides about the traffic once per stream, not once per window:
        ``params`` (bound to the window ``d``, canonical order) with the decision taken on
        the ``evidence`` of the windows before and on ``d``'s, and ``d``'s evidence, which
        the stream tracker adds up as (sum, weight) over its windows. Nothing by default."""
        return params, None

    def session(self, layout: Layout, n_targets: int) -> Session:
        return Session(self, layout, n_targets)

    def associate_incrementally(
        self, layout: Layout, detections: Detections, n_targets: int
    ) -> np.ndarray:
        """Feed ``detections`` segment by segment through a session; labels in input order."""
        session = self.session(layout, n_targets)
        order = []
        labels = np.zeros(0, dtype=np.int64)
        for seg in segments(layout.n_sensors, self.config.segment_size):
            idx = np.flatnonzero(np.isin(detections.sensor_index, seg))
            order.append(idx)
            labels = session.add_segment(detections.subset(idx))
        out = np.full(len(detections), -1, dtype=np.int64)
        out[np.concatenate(order)] = labels
        return out


METHODS: Registry[type[Associator]] = Registry('method')


def register(cls: type[Associator]) -> type[Associator]:
    """Class decorator: make an associator selectable by its ``name`` everywhere."""
    return METHODS.add(cls.name, cls)


def available_methods() -> list[str]:
    """Every registered method (importing this module first runs the package's
    ``__init__``, which registers the built-in ones)."""
    return sorted(METHODS.names())


def make_associator(name: str, config: AssociatorConfig | None = None) -> Associator:
    return METHODS.get(name)(config)
