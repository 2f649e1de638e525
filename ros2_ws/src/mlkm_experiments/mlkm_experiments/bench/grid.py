"""Accuracy grid: every method on (targets, sensors) cells in paper and clutter mode.

The same seeded datasets for every method. Each (method, cell, mode) runs in a child process
with a time budget; a method that exceeds it is stopped and the report says after how many
datasets.
"""

from __future__ import annotations

import time

from mlkm_core.associators import make_associator
from mlkm_core.simulator import simulate

from .common import (
    CLUTTER,
    MODES,
    Log,
    dataset_seed,
    run_budgeted,
    sim_config,
    summarise,
    timed_row,
)

CELLS = ((10, 10), (50, 20), (200, 50), (1000, 100))
SEEDS_FULL = {(10, 10): 40, (50, 20): 30, (200, 50): 8, (1000, 100): 2}
SEEDS_QUICK = {(10, 10): 4, (50, 20): 3, (200, 50): 1, (1000, 100): 1}
# time budget [s] of one (method, cell, mode): all its datasets
BUDGET = {(10, 10): 60.0, (50, 20): 120.0, (200, 50): 150.0, (1000, 100): 120.0}


def grid_job(method: str, mode: str, cell: tuple[int, int], seeds: list[int]):
    """Job factory for ``run_budgeted``: simulate dataset k of the cell, associate, score."""

    def make_job():
        assoc = make_associator(method)

        def job(k: int) -> dict:
            ds = simulate(sim_config(mode, *cell), seeds[k])
            return timed_row(ds, lambda d: assoc.associate(d.layout, d.detections, d.n_targets))

        return job

    return make_job


def run_grid(methods: list[str], seeds_per_cell: dict, log: Log) -> dict:
    out: dict = {
        'cells': [],
        'clutter': CLUTTER,
        'budget_s': {f'{a}x{b}': v for (a, b), v in BUDGET.items()},
    }
    for cell in CELLS:
        n = seeds_per_cell[cell]
        seeds = [dataset_seed(*cell, k) for k in range(n)]
        for mode in MODES:
            entry = {
                'targets': cell[0],
                'sensors': cell[1],
                'mode': mode,
                'seeds': seeds,
                'methods': {},
            }
            for m in methods:
                t0 = time.monotonic()
                rows, status = run_budgeted(grid_job(m, mode, cell, seeds), n, BUDGET[cell])
                entry['methods'][m] = {'summary': summarise(rows), 'status': status, 'runs': rows}
                s = entry['methods'][m]['summary']
                log(
                    f'grid {cell[0]}/{cell[1]} {mode:7s} {m:12s} '
                    f'{s.get("accuracy_mean", float("nan")) * 100:7.3f}% '
                    f'n={s["n"]} {status} ({time.monotonic() - t0:.1f} s)'
                )
            out['cells'].append(entry)
    return out


def grid_cell(grid: dict, t: int, s: int, mode: str) -> dict | None:
    for c in grid.get('cells', []):
        if (c['targets'], c['sensors'], c['mode']) == (t, s, mode):
            return c
    return None
