"""The length noise fitted where lengths are reported exactly (to their resolution): a hand-made
fit, the cost of one resolution step, and real traffic where a step tells two cars apart."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mlkm_core.associators import make_associator
from mlkm_core.metrics import accuracy
from mlkm_core.model import length
from mlkm_core.types import Detections

STEP = 0.03  # [m] a length resolution, about 0.1 ft as in NGSIM


def _exact_links(n_links: int, off: int) -> tuple[Detections, np.ndarray, np.ndarray]:
    """``n_links`` links a -> b of vehicles whose lengths lie on a STEP grid and are reported
    exactly, ``off`` of them between lengths one step apart."""
    rng = np.random.default_rng(3)
    size = 4.0 + STEP * rng.integers(0, 40, n_links)
    other = size.copy()
    other[:off] += STEP
    n = 2 * n_links
    d = Detections(
        np.tile([0, 1], n_links), np.arange(n, dtype=float), np.full(n, 10.0),
        length=np.ravel(np.column_stack([size, other])),
    )  # fmt: skip
    return d, np.arange(0, n, 2), np.arange(1, n, 2)


def test_exact_lengths_get_a_noise_well_below_their_resolution():
    d, a, b = _exact_links(400, 2)
    assert length.resolution(d.length) == pytest.approx(STEP)
    fit = length.fit_links(d, a, b)
    # 2 of 400 links differ by a step: the noise whose difference passes half a step that often
    z = 2.807  # standard normal quantile of 1 - 2 / 400 / 2
    assert fit.length_noise == pytest.approx(STEP / (2 * math.sqrt(2) * z), rel=1e-3)
    # no link differs by a step: one link's worth, no zero noise
    d, a, b = _exact_links(400, 0)
    assert length.FLOOR_LENGTH < length.fit_links(d, a, b).length_noise < fit.length_noise


def _step_price(params: length.LengthParams) -> float:
    """The cost of a link to a length one STEP off the track's, less that of an equal one."""
    d = Detections(
        np.array([0, 1, 1]), np.array([0.0, 10.0, 10.5]), np.full(3, 10.0),
        length=np.array([4.05, 4.05, 4.05 + STEP]),
    )  # fmt: skip
    tracks = length.LengthCue(d, params).tracks(True)
    tracks.grow(1)
    tracks.start(np.array([0]), np.array([0]))
    same, off = tracks.cost(np.array([0, 0]), np.array([1, 2]))
    return float(off - same)


def test_one_step_apart_is_another_vehicle_under_the_exact_fit():
    d, a, b = _exact_links(400, 2)
    fit = length.fit_links(d, a, b)
    # about the price of an outlier, -log eps with eps = 2 / 400 ...
    assert _step_price(fit) > 5.0
    # ... where a noise of 5 cm would take the step for noise
    assert _step_price(length.LengthParams(0.05, fit.length_outlier)) < 0.5


def test_a_length_step_tells_two_cars_apart_on_real_traffic(ngsim_loops, monkeypatch):
    """NGSIM I-80, five open loops 100 m apart from the real bench's first placement, lane and
    length: a car of 4.08 m that is first seen at the second loop, 1.6 s ahead of two cars of
    4.05 m in its lane. Under a 5 cm noise the tracks take it for the first of those and leave
    the second's tail to begin a track; under the fitted noise every vehicle is its own track."""
    ds = ngsim_loops(5, False)
    d = ds.detections

    def found() -> float:
        labels = make_associator('assignment').associate(ds.layout, d, ds.n_targets)
        return accuracy(labels, d.target).accuracy

    assert found() == 1.0
    monkeypatch.setattr(length, 'exact_noise', lambda lengths, dl: 0.05)
    assert found() < 1.0
