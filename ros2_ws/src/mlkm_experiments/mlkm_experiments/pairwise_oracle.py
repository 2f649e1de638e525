"""How far time and speed can carry a pairwise link cost on real stop-and-go traffic.

``python -m mlkm_experiments.pairwise_oracle [--placements N]`` (from the repository root)
links the closed-road NGSIM I-80 loops of ``mlkm bench --only real`` (5, 10 and 20 stations
over 400 m, the benchmark's placements 1..N) gap by gap with an *oracle* pairwise cost, one
that no method has: per station gap, a Gaussian of (the travel time's residual against the
trapezoid of the speeds at both ends, the slowness change), its mean and covariance fitted on
that gap's true links, every detection linked by an optimal assignment
(``scipy.optimize.linear_sum_assignment``) to the next station's. It prints the accuracy of
that and of ``assignment`` per dataset. Where ``assignment``, whose cost is fitted without the
truth, links about as well as a cost fitted on the truth, its errors are not those of a badly
fitted cost: the vehicles it confuses are as alike in time and speed as the true links are
scattered, and the evidence to tell them apart has to come from elsewhere (more stations,
lanes, lengths, or a model of the whole track).
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np
from scipy.optimize import linear_sum_assignment

from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.metrics import accuracy
from mlkm_core.trajectories import read_trajectories
from mlkm_core.types import Dataset

from .bench import real
from .bench.common import time_speed_only


def oracle_labels(ds: Dataset) -> np.ndarray:
    """Labels of the gap-by-gap oracle (module docstring) on a closed-road dataset."""
    d, x = ds.detections, ds.layout.positions
    u = 1.0 / d.velocity
    at = [np.flatnonzero(d.sensor_index == s) for s in range(ds.layout.n_sensors)]
    labels = np.full(len(d), -1, np.int64)
    labels[at[0]] = np.arange(at[0].size)
    fresh = at[0].size
    for s in range(ds.layout.n_sensors - 1):
        a, b = at[s], at[s + 1]
        dx = x[s + 1] - x[s]
        where = {int(t): k for k, t in enumerate(d.target[a])}
        pairs = [(where[int(t)], j) for j, t in enumerate(d.target[b]) if int(t) in where]
        ia, jb = (np.array(c, np.int64) for c in zip(*pairs, strict=True))
        ua, ub = u[a][:, None], u[b][None, :]
        resid = d.stamp[b][None, :] - d.stamp[a][:, None] - dx * (ua + ub) / 2
        change = u[b][None, :] - u[a][:, None]
        z = np.column_stack([resid[ia, jb], change[ia, jb]])
        mean, inv = z.mean(axis=0), np.linalg.inv(np.cov(z.T))
        e0, e1 = resid - mean[0], change - mean[1]
        cost = inv[0, 0] * e0 * e0 + 2 * inv[0, 1] * e0 * e1 + inv[1, 1] * e1 * e1
        rows, cols = linear_sum_assignment(cost)
        labels[b[cols]] = labels[a[rows]]
        left = labels[b] < 0
        labels[b[left]] = fresh + np.arange(int(left.sum()))
        fresh += int(left.sum())
    return labels


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m mlkm_experiments.pairwise_oracle')
    parser.add_argument('--placements', type=int, default=8, help='datasets per cell (1..N)')
    args = parser.parse_args(argv)
    warnings.simplefilter('ignore')
    traj = read_trajectories(real.DATA)
    print('stations placement first_m oracle_% assignment_%')
    for stations in real.STATIONS:
        seeds = list(range(1, args.placements + 1))
        for seed, ds in zip(seeds, real.datasets(traj, stations, 'closed', seeds), strict=True):
            ds = time_speed_only(ds)
            target = ds.detections.target
            plain = make_associator('assignment', AssociatorConfig()).associate(
                ds.layout, ds.detections, ds.n_targets
            )
            print(
                f'{stations} {seed} {real.placement(seed):.1f} '
                f'{100 * accuracy(oracle_labels(ds), target).accuracy:.2f} '
                f'{100 * accuracy(plain, target).accuracy:.2f}',
                flush=True,
            )
    return 0


if __name__ == '__main__':
    sys.exit(main())
