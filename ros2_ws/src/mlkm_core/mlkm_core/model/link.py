"""The link model: a motion model plus the cues, the one object every method scores with.

``LinkModel`` holds many tracks (ids 0..n-1): their motion state (a ``motion.MotionModel``
chosen by name) and their state of every cue bound in ``params.cues`` (``cues.CueSet``). The
cost of a detection joining a track is the motion model's negative log-likelihood plus the
sum of the cues' costs. The methods call ``grow``, ``start``, ``predict``, ``gate_window``,
``cost`` and ``update`` and never name a cue.
"""

from __future__ import annotations

import numpy as np

from mlkm_core.model.cues import CueSetTracks, TrackArrays
from mlkm_core.model.kalman import KalmanModel
from mlkm_core.model.motion import MODELS, MotionModel, MotionParams, PairwiseModel, Prediction

__all__ = ['KalmanModel', 'LinkModel', 'PairwiseModel', 'make_model']


def make_model(
    name: str, params: MotionParams, rows: dict[str, np.ndarray] | None = None
) -> MotionModel:
    """A new, empty motion model chosen by name (``pairwise`` or ``kalman``); ``rows`` gives
    per-track parameters (``kalman`` only)."""
    cls = MODELS.get(name)
    return cls(params) if rows is None else cls(params, rows)


class LinkModel:
    """Motion model and cues of many tracks.

    ``cap``: past this squared Mahalanobis distance the motion term grows linearly instead of
    quadratically (a few wrong links do not dominate a track's likelihood); None: no cap.
    """

    def __init__(
        self,
        params: MotionParams,
        motion: str = 'pairwise',
        rows: dict[str, np.ndarray] | None = None,
        cap: float | None = None,
    ) -> None:
        self.params = params
        self.motion = make_model(motion, params, rows)
        cues = params.cues
        self.cues: CueSetTracks | None = None
        if cues is not None and cues.active:
            # a filter keeps a track's whole history; the cues do the same
            self.cues = cues.tracks(accumulate=self.motion.keeps_history)
        self.cap = cap

    def grow(self, n: int) -> None:
        """Make room for ``n`` more tracks."""
        self.motion.grow(n)
        if self.cues is not None:
            self.cues.grow(n)

    def start(
        self,
        tracks: np.ndarray,
        x: float | np.ndarray,
        t: np.ndarray,
        u: np.ndarray,
        det: np.ndarray | None,
    ) -> None:
        """Start ``tracks`` from detection ``det[i]`` each (position x, stamp t, slowness u;
        ``det`` None: detections the cues were not bound to, which then play no part)."""
        self.motion.start(tracks, x, t, u)
        if self.cues is not None and det is not None:
            self.cues.start(tracks, det)

    def predict(self, tracks: np.ndarray, x: float | np.ndarray) -> Prediction:
        return self.motion.predict(tracks, x)

    def gate_window(self, pred: Prediction) -> tuple[np.ndarray, np.ndarray]:
        return self.motion.gate_window(pred)

    def motion_cost(
        self, pred: Prediction, t: np.ndarray, u: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(NLL, squared Mahalanobis distance) of the motion term alone (capped)."""
        nll, d2 = self.motion.cost(pred, t, u)
        if self.cap is not None:
            nll = nll - 0.5 * np.maximum(d2 - self.cap, 0.0)
        return nll, d2

    def cue_cost(self, tracks: np.ndarray, det: np.ndarray | None) -> np.ndarray | float:
        """Sum of the cues' costs of detection ``det[i]`` joining track ``tracks[i]``."""
        if self.cues is None or det is None:
            return 0.0
        return self.cues.cost(tracks, det)

    def cost(
        self, pred: Prediction, t: np.ndarray, u: np.ndarray, det: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(NLL, squared Mahalanobis distance of the motion term) of detection i (stamp t[i],
        slowness u[i], index det[i]) joining the track of ``pred`` row i."""
        nll, d2 = self.motion_cost(pred, t, u)
        if self.cues is not None and det is not None:
            nll = nll + self.cues.cost(pred.tracks, det)
        return nll, d2

    def update(
        self, pred: Prediction, t: np.ndarray, u: np.ndarray, det: np.ndarray | None
    ) -> None:
        """Take detection i into the track of ``pred`` row i (each track at most once)."""
        if self.cues is not None and det is not None:
            self.cues.update(pred.tracks, det)
        self.motion.update(pred, t, u)

    @property
    def cue_state(self) -> tuple[TrackArrays, ...] | None:
        return None if self.cues is None else self.cues.state

    def load_cues(self, state: tuple[TrackArrays, ...] | None) -> None:
        """Continue the cues from a saved ``cue_state``."""
        if self.cues is not None and state is not None:
            self.cues.load(state)
