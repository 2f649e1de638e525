"""``python -m mlkm_experiments.pairwise_oracle``: the gap-by-gap oracle links a hand-made
closed road exactly and links by the fitted cost, not by the order of the rows."""

from __future__ import annotations

import numpy as np

from mlkm_core.metrics import accuracy
from mlkm_core.types import Dataset, Detections, Layout
from mlkm_experiments.pairwise_oracle import oracle_labels


def test_the_oracle_links_vehicles_that_overtake_between_stations():
    # 12 vehicles 2 s apart at 10..21 m/s over three stations 200 m apart: the fast ones
    # overtake the slow ones, so the order at one station is not the order at the next
    layout = Layout(600.0, np.array([100.0, 300.0, 500.0]))
    speeds = 10.0 + np.arange(12.0)
    rng = np.random.default_rng(0)
    rows = []
    for k, v in enumerate(speeds):
        for s, x in enumerate(layout.positions):
            rows.append(
                (s, 2.0 * k + (x - 100.0) / v + rng.normal(0, 0.05), v + rng.normal(0, 0.2), k)
            )
    s, t, v, k = (np.array(c) for c in zip(*rows, strict=True))
    order = rng.permutation(s.size)
    d = Detections(s[order].astype(np.int64), t[order], v[order], k[order].astype(np.int64))
    ds = Dataset(layout, d, 12)
    labels = oracle_labels(ds)
    assert accuracy(labels, d.target).accuracy == 1.0
    at_last = d.sensor_index == 2
    # the arrival order at the last station differs from the first's: order alone would fail
    first = np.argsort(d.stamp[d.sensor_index == 0])
    last = np.argsort(d.stamp[at_last])
    assert not np.array_equal(d.target[d.sensor_index == 0][first], d.target[at_last][last])
