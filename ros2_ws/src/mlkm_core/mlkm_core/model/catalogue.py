"""The registered cues, and binding and fitting them all at once.

A new cue is one module (see ``cues``) and one entry in the tuple registered below (or one
``register_cue`` call). Costs are summed in the order of registration.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mlkm_core.model import lane, lane_order, length
from mlkm_core.model.cues import CueKind, CueSet
from mlkm_core.registry import Registry
from mlkm_core.types import Detections, Layout

#: the cues in the order their costs are summed
CUES: Registry[CueKind] = Registry('cue')
for _kind in (lane_order.KIND, length.KIND, lane.KIND):
    CUES.add(_kind.name, _kind)


def register_cue(kind: CueKind) -> None:
    """Add a cue (after the built-in ones); its name must be new."""
    CUES.add(kind.name, kind)


def unregister_cue(name: str) -> None:
    """Remove a cue registered with ``register_cue``."""
    CUES.remove(name)


def available_cues() -> list[str]:
    return CUES.names()


def bind_cues(layout: Layout, d: Detections, params: dict[str, Any]) -> CueSet:
    """Every cue with parameters in ``params`` bound to ``d`` (those the data hold nothing for
    are left out; their parameters are kept)."""
    bound, off = [], {}
    for k in CUES.values():
        cue = None if params.get(k.name) is None else k.bind(layout, d, params[k.name])
        if cue is not None:
            bound.append(cue)
        elif params.get(k.name) is None:
            off[k.name] = f'not fitted: no {k.needs} found'
        else:
            off[k.name] = f'the detections hold no {k.needs}'
    tied = frozenset(k.name for k in CUES.values() if not k.reusable)
    return CueSet(tuple(bound), dict(params), tied, off)


def generic_cues(layout: Layout, d: Detections) -> CueSet | None:
    """The cues with generic parameters that the data hold something for; None: none."""
    cues = bind_cues(
        layout, d, {k.name: k.generic for k in CUES.values() if k.generic is not None}
    )
    return cues if cues.active else None


def fit_cues(layout: Layout, d: Detections, labels: np.ndarray) -> dict[str, Any]:
    """The parameters of the cues fitted once from the tracks ``labels`` (not those refined
    over link passes: ``refined_kinds``)."""
    return {k.name: k.fit(layout, d, labels) for k in CUES.values() if k.rounds == 0}


def refined_kinds() -> list[CueKind]:
    """The cues whose fit is refined by link passes with the cue itself."""
    return [k for k in CUES.values() if k.rounds > 0]
