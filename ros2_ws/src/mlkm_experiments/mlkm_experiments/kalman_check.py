"""Which search ``multiframe`` should run: its model check against what each search gives.

``python -m mlkm_experiments.kalman_check [--placements N] [--families] [--cache-dir DIR]``
(from the repository root) runs, on the NGSIM I-80 loops of ``mlkm bench --only real`` at 5
stations (closed and open road, the benchmark's placements 1..N, time and speed only) and,
with ``--families``, on the first five seeds of each SUMO family of ``mlkm bench --only
sumo`` (both variants), ``assignment`` and ``multiframe`` twice: once with its search under
the Kalman model, once under the pairwise model's Markov chain, whatever its check decides
(the check replaced for the run).
Per dataset it prints both accuracies, what the check decided, and the two measures a check
could use:

- ``lead``: the check ``multiframe`` makes (``pairwise_fit.kalman_lead``: NLL per link of the
  Kalman model minus the pairwise model's on the links of the pairwise pass);
- ``persistence``: the correlation, over the same links, of a vehicle's deviation from the
  traffic around it at both ends of a link (``deviations``): the structure the Kalman model
  relies on (a cruise speed of the vehicle's own, learnt from its past detections).

A check is right on a dataset where it picks the search that links better there.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path
from unittest.mock import patch

import numpy as np

from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.associators import multiframe as mf
from mlkm_core.associators.pairwise_fit import kalman_lead
from mlkm_core.metrics import accuracy
from mlkm_core.types import Dataset, Detections, link_pairs

from .bench import real
from .bench.common import time_speed_only

#: detections on each side, at the same station and in time order, whose median slowness is
#: the traffic a detection deviates from
NEIGHBOURS = 8
FAMILY_SEEDS = 5


def deviations(d: Detections, neighbours: int = NEIGHBOURS) -> np.ndarray:
    """Each detection's slowness [s/m] minus the median slowness of the ``2 * neighbours + 1``
    detections nearest to it in time at its station (fewer at a station that has fewer)."""
    u = 1.0 / d.velocity
    out = np.empty_like(u)
    width = 2 * neighbours + 1
    for s in np.unique(d.sensor_index):
        at = np.flatnonzero(d.sensor_index == s)
        at = at[np.argsort(d.stamp[at], kind='stable')]
        if at.size <= width:
            out[at] = u[at] - np.median(u[at])
            continue
        starts = np.clip(np.arange(at.size) - neighbours, 0, at.size - width)
        windows = np.lib.stride_tricks.sliding_window_view(u[at], width)[starts]
        out[at] = u[at] - np.median(windows, axis=1)
    return out


def persistence(d: Detections, labels: np.ndarray) -> float:
    """Correlation of ``deviations`` at both ends of the links of ``labels``."""
    e = deviations(d)
    a, b = link_pairs(d, labels)
    return float(np.corrcoef(e[a], e[b])[0, 1])


def check(ds: Dataset, config: AssociatorConfig) -> dict:
    """The module docstring's figures on one dataset. The check's inputs (the pairwise pass
    and the calibrated model) are taken where ``multiframe`` makes it."""
    t = ds.detections.target
    decide = mf.kalman_fits
    out: dict = {}

    def spy(layout, d, labels, params):
        out['kalman_fits'] = bool(decide(layout, d, labels, params))
        out['lead'] = float(kalman_lead(layout, d, labels, params))
        out['persistence'] = persistence(d, labels)
        return out['kalman_fits']

    def labels_of(name: str) -> np.ndarray:
        return make_associator(name, config).associate(ds.layout, ds.detections, ds.n_targets)

    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        out['assignment'] = accuracy(labels_of('assignment'), t).accuracy
        with patch.object(mf, 'kalman_fits', spy):
            out['multiframe'] = accuracy(labels_of('multiframe'), t).accuracy
        for name, fits in (('kalman_search', True), ('pairwise_search', False)):
            with patch.object(mf, 'kalman_fits', lambda *_, fits=fits: fits):
                out[name] = accuracy(labels_of('multiframe'), t).accuracy
    return out


def ngsim_sets(placements: int):
    from mlkm_core.trajectories import read_trajectories

    traj = read_trajectories(real.DATA)
    seeds = list(range(1, placements + 1))
    for road in real.VARIANTS_ROAD:
        for seed, ds in zip(seeds, real.datasets(traj, 5, road, seeds)):
            yield f'ngsim 5 {road} {seed} time_speed', time_speed_only(ds), AssociatorConfig()


def family_sets(cache_dir: Path):
    from mlkm_sumo.families import draw

    from .bench.sumo_data import DatasetCache, load
    from .bench.sumo_families import FAMILY_CELLS

    cache = DatasetCache(cache_dir)
    for family in FAMILY_CELLS:
        for seed in range(1, FAMILY_SEEDS + 1):
            dr = draw(family, seed)
            config = AssociatorConfig(entries=dr.entries, exits=dr.exits)
            for variant in ('time_speed', 'lane_length'):
                ds = load(cache.family(dr), variant)
                yield f'family {family} {seed} {variant}', ds, config


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--placements', type=int, default=8, help='NGSIM placements (8)')
    ap.add_argument('--families', action='store_true', help='the SUMO families too')
    ap.add_argument('--cache-dir', type=Path, help='keep the SUMO datasets here')
    args = ap.parse_args(argv)
    sets = list(ngsim_sets(args.placements))
    if args.families:
        import tempfile

        root = args.cache_dir or Path(tempfile.mkdtemp(prefix='mlkm_kalman_check_'))
        sets = [*sets, *family_sets(root)]
    for name, ds, config in sets:
        row = {'dataset': name, **check(ds, config)}
        print(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}))
        sys.stdout.flush()
    return 0


if __name__ == '__main__':
    sys.exit(main())
