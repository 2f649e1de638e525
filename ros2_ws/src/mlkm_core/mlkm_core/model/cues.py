"""Cues: the terms of a link's cost beyond the motion model, and the interface they share.

A cue is what a detection tells about its vehicle besides its time and speed: the lane, the
vehicle's length, the order of passage within a lane in a queue, ... Each cue is one module
(``lane``, ``length``, ``lane_order``) that defines

* a ``CueKind``, registered once in ``catalogue``: its name; what it needs from the data
  (``CueSet.off`` says so for a cue left off); its generic parameters (used
  before anything is fitted; None when it has none); ``fit``, its parameters from the tracks
  of a pass over the detections being associated (None switches it off); ``rounds``, how
  many link passes refine the fit (a cue learnt from the very tracks it changes); and
  ``bind``, the cue on one set of detections, with what it needs from them precomputed
  (None when they hold nothing for it, e.g. no lane is known);
* a ``Cue`` (the bound cue), whose ``tracks`` gives a ``CueTracks``: the cue's state of many
  tracks (ids 0..n-1, parallel to a motion model) with ``grow``, ``start``, ``cost`` and
  ``update``. A cost is a bounded negative log-likelihood *ratio* against the population (how
  the detection would look if it were not the track's): a detection that starts a track pays
  nothing, and an unknown value costs 0.

``CueSet`` holds the bound cues of one set of detections and sums their costs in the order
of registration; ``link.LinkModel`` adds that sum to the motion model's cost, and every
method scores its links through a ``LinkModel``, so none of them names a cue.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from mlkm_core.types import Detections, Layout


class TrackArrays:
    """Named per-track arrays (one row per track) with an initial value per field."""

    def __init__(self, fields: dict[str, tuple[Any, type]], n: int = 0) -> None:
        self.fields = fields
        self.arrays = {k: np.full(n, fill, dtype) for k, (fill, dtype) in fields.items()}

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def grow(self, n: int) -> None:
        for k, (fill, dtype) in self.fields.items():
            self.arrays[k] = np.concatenate([self.arrays[k], np.full(n, fill, dtype)])

    def take(self, rows: np.ndarray) -> TrackArrays:
        out = TrackArrays(self.fields)
        out.arrays = {k: v[rows] for k, v in self.arrays.items()}
        return out

    def copy(self) -> TrackArrays:
        out = TrackArrays(self.fields)
        out.arrays = {k: v.copy() for k, v in self.arrays.items()}
        return out


class CueTracks(ABC):
    """One cue's state of many tracks; ``FIELDS`` names its per-track arrays."""

    FIELDS: ClassVar[dict[str, tuple[Any, type]]] = {}

    def __init__(self, accumulate: bool) -> None:
        # accumulate: the motion model keeps a track's whole history (a filter), not just
        # its last detection, and a cue that can should do the same
        self.accumulate = accumulate
        self.state = TrackArrays(self.FIELDS)

    def grow(self, n: int) -> None:
        """Make room for ``n`` more tracks."""
        self.state.grow(n)

    def load(self, state: TrackArrays) -> None:
        """Continue from a saved state (copied)."""
        self.state = state.copy()

    @abstractmethod
    def start(self, tracks: np.ndarray, det: np.ndarray) -> None:
        """Start ``tracks`` from detection ``det[i]`` each."""

    @abstractmethod
    def cost(self, tracks: np.ndarray, det: np.ndarray) -> np.ndarray:
        """NLL ratio of detection ``det[i]`` joining track ``tracks[i]`` (0 when unknown)."""

    @abstractmethod
    def update(self, tracks: np.ndarray, det: np.ndarray) -> None:
        """Take detection ``det[i]`` into track ``tracks[i]``."""


class Cue(ABC):
    """A cue bound to one set of detections (indices of a ``CueTracks`` refer to them)."""

    name: ClassVar[str]

    @abstractmethod
    def tracks(self, accumulate: bool) -> CueTracks:
        """A new, empty per-track state."""


@dataclass(frozen=True)
class CueKind:
    """How one cue is fitted and bound; registered once (``catalogue.register_cue``)."""

    name: str
    #: what the cue needs from the detections (says why it is off when they lack it)
    needs: str
    #: (layout, detections, parameters) -> the bound cue, None when the data hold nothing for it
    bind: Callable[[Layout, Detections, Any], Cue | None]
    #: (layout, detections, labels of a pass) -> parameters; None switches the cue off
    fit: Callable[[Layout, Detections, np.ndarray], Any]
    #: parameters before anything is fitted; None: the cue needs tracks first
    generic: Any = None
    #: link passes that refine the fit from their own tracks (0: fitted once per pass)
    rounds: int = 0
    #: False: the parameters are learnt from, and tied to, the detections they were fitted on
    #: (they cannot be carried to other detections)
    reusable: bool = True


class CueSetTracks:
    """The state of every cue of a ``CueSet`` for many tracks; costs summed in order."""

    def __init__(self, parts: list[CueTracks]) -> None:
        self.parts = parts

    def grow(self, n: int) -> None:
        for p in self.parts:
            p.grow(n)

    def start(self, tracks: np.ndarray, det: np.ndarray) -> None:
        for p in self.parts:
            p.start(tracks, det)

    def cost(self, tracks: np.ndarray, det: np.ndarray) -> np.ndarray:
        out = np.zeros(det.size)
        for p in self.parts:
            out += p.cost(tracks, det)
        return out

    def update(self, tracks: np.ndarray, det: np.ndarray) -> None:
        for p in self.parts:
            p.update(tracks, det)

    @property
    def state(self) -> tuple[TrackArrays, ...]:
        return tuple(p.state for p in self.parts)

    def load(self, state: tuple[TrackArrays, ...]) -> None:
        for p, s in zip(self.parts, state, strict=True):
            p.load(s)


class CueSet:
    """The cues bound to one set of detections, with the parameters they were bound with."""

    def __init__(
        self,
        cues: tuple[Cue, ...],
        params: dict[str, Any],
        tied: frozenset[str] = frozenset(),
        off: dict[str, str] | None = None,
    ) -> None:
        self.cues = cues
        self.params = params  # parameters by cue name (also of cues left unbound)
        self.tied = tied  # names of the parameters tied to these detections
        self.off = off or {}  # why each registered cue that is not bound is off

    @property
    def active(self) -> bool:
        """Whether any cue scores links (the data hold something for one)."""
        return bool(self.cues)

    @property
    def reusable(self) -> bool:
        """Whether the parameters alone rebuild every cue on other detections."""
        return all(self.params.get(k) is None for k in self.tied)

    def carried(self) -> dict[str, Any]:
        """The parameters that other detections can be bound with (``catalogue.bind_cues``)."""
        return {k: v for k, v in self.params.items() if k not in self.tied}

    def get(self, name: str) -> Cue | None:
        """The bound cue called ``name`` (None: not bound)."""
        return next((c for c in self.cues if c.name == name), None)

    def tracks(self, accumulate: bool) -> CueSetTracks:
        return CueSetTracks([c.tracks(accumulate) for c in self.cues])


def take_state(state: tuple[TrackArrays, ...], rows: np.ndarray) -> tuple[TrackArrays, ...]:
    """The saved state of the given rows (repeats allowed), in that order."""
    return tuple(s.take(rows) for s in state)
