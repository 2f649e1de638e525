"""Time gates: the candidate pairs of one window per track, alone and within groups."""

import numpy as np

from mlkm_core.associators.gating import gate_pairs, gate_pairs_grouped


def _pairs(r: np.ndarray, c: np.ndarray) -> list[tuple[int, int]]:
    return list(zip(r.tolist(), c.tolist(), strict=True))


def test_gate_pairs_window():
    r, c = gate_pairs(
        np.array([1.0, 5.0]), np.array([0.5, 2.0]), np.array([4.0, 1.2, 9.0, 6.5, 0.6])
    )
    assert sorted(_pairs(r, c)) == [(0, 1), (0, 4), (1, 0), (1, 3)]


def test_grouped_gates_search_their_own_group_ends_included_by_row_then_value():
    # rows: group 0 window [0.5, 1.5], group 1 window [0.5, 1.5], group 0 window [4, 6]
    r, c = gate_pairs_grouped(
        np.array([0, 1, 0]),
        np.array([1.0, 1.0, 5.0]),
        np.array([0.5, 0.5, 1.0]),
        np.array([0, 0, 1, 0, 1, 0]),
        np.array([1.5, 0.5, 1.2, 5.0, 4.0, 1.0]),
    )
    # 1.5 and 0.5 lie on the first window's ends; 4.0 on the last's, but in group 1
    assert _pairs(r, c) == [(0, 1), (0, 5), (0, 0), (1, 2), (2, 3)]


def test_grouped_gates_equal_values_in_index_order_and_empty_gates():
    r, c = gate_pairs_grouped(
        np.array([3, 3, 7]),
        np.array([2.0, np.nan, 2.0]),
        np.array([1.0, 1.0, 1.0]),
        np.array([3, 3, 3, 5]),
        np.array([2.5, 2.5, 9.0, 2.0]),
    )
    # a NaN prediction gates nothing; group 7 has no values
    assert _pairs(r, c) == [(0, 0), (0, 1)]


def test_grouped_gates_equal_one_gate_per_group():
    rng = np.random.default_rng(4)
    n_r, n_v, groups = 300, 1000, 10
    row_group = rng.integers(0, groups, n_r)
    centre = rng.uniform(0, 100, n_r)
    half = rng.uniform(0, 5, n_r)
    value_group = rng.integers(0, groups, n_v)
    values = np.round(rng.uniform(0, 100, n_v), 1)  # rounded: equal values and ends occur
    r, c = gate_pairs_grouped(row_group, centre, half, value_group, values)
    want = []
    for i in range(n_r):
        mine = np.flatnonzero(value_group == row_group[i])
        _, cols = gate_pairs(centre[i : i + 1], half[i : i + 1], values[mine])
        want += [(i, int(j)) for j in mine[cols]]
    assert len(want) > n_r  # the windows hold values
    assert _pairs(r, c) == want
