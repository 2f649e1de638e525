"""What decides a link in ``mlkm_robust``: its tracks against ``assignment``'s, dataset by dataset.

``python -m mlkm_experiments.robust_links [--parts ngsim,sim,sumo] [--seeds N]`` (from the
repository root) prints one line per dataset:

* ``differ``: detections whose track differs between ``mlkm_robust`` and ``assignment`` (after
  the best one-to-one matching of the two methods' tracks; an unassigned detection matches an
  unassigned one only), and links (consecutive detections of a track) found by one method only;
* ``whole``: Layer 1's K-means++ clusters that hold exactly one detection of each sensor of
  their segment, over all clusters;
* ``segs``, ``allflag``, ``kept``: segments, those in which the error detection (the paper's
  three rules and ``mlkm_robust``'s fourth) flags every sensor, and the sensors whose Layer 1
  labels survive it over all sensors, recomputed with the product's own functions. In a
  segment with every sensor flagged, ``correct_by_assignment`` keeps nothing of the clusters
  but the choice of its anchor (the sensor with the most distinct cluster labels, one track
  per detection) and links every other sensor of the segment to it by the pairwise assignment;
* ``forward``: detections whose track differs between ``assignment`` and ``mlkm_robust`` with
  Layer 1 left out (every sensor flagged, each segment's first sensor the anchor, so that the
  correction is a forward pass; ``ForwardAnchor``): what the segments and Layer 3 change;
* ``anchor``: detections whose track differs between ``mlkm_robust`` and ``ForwardAnchor``:
  what the anchor Layer 1 picks (and the backward pass from it to the segment's first sensor)
  changes.

The datasets are the benchmark's: NGSIM I-80 virtual loops (``bench.real``: 5, 10, 20
stations, closed and open, with (time, speed) only and with lane and length), the simulator at
50 targets and 20 sensors in paper and clutter mode (``bench.common``) and SUMO's highway,
congested and ramps scenarios at 50 vehicles and 20 stations, measured without noise and with
the benchmark's clutter (``bench.sumo_data``: misses, stamp jitter, false alarms). Each method
runs with the default ``AssociatorConfig`` (K = 5), plus the ramps for SUMO.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from collections.abc import Iterator

import numpy as np
from scipy.optimize import linear_sum_assignment

from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.associators.base import canonical_order
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.associators.kmeans import kmeans_labels
from mlkm_core.associators.mlkm import detect_errors
from mlkm_core.associators.mlkm_robust import (
    RobustMLKM,
    correct_by_assignment,
    implausible_links,
)
from mlkm_core.metrics import score
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Dataset, Detections, Layout, link_pairs, segments
from mlkm_experiments.bench.common import time_speed_only

PARTS = ('ngsim', 'sim', 'sumo')
SUMO_SCENARIOS = ('highway', 'congested', 'ramps')
SUMO_VEHICLES = 50
SUMO_STATIONS = 20
#: the figures of ``compare`` that the last line sums over the datasets
SUMMED = (
    'detections',
    'differ',
    'segments',
    'all_flagged',
    'forward',
    'anchor',
    'whole',
    'clusters',
)


class ForwardAnchor(RobustMLKM):
    """``mlkm_robust`` without Layer 1 (not registered): every sensor of a segment is flagged
    and its first sensor is the anchor, so the Layer 2 correction links the segment forward."""

    def solve_segment(
        self,
        layout: Layout,
        d: Detections,
        n_targets: int,
        p: MotionParams,
        glob: np.ndarray | None = None,
    ) -> np.ndarray:
        first = d.sensor_index == d.sensor_index.min()
        # the first sensor has the most distinct labels (ties go to it), so it is the anchor
        labels = np.full(len(d), int(first.sum()), dtype=np.int64)
        labels[first] = np.arange(int(first.sum()))
        flagged = frozenset(int(s) for s in np.unique(d.sensor_index))
        labels = correct_by_assignment(layout.positions, d, labels, flagged, p, glob)
        return np.unique(labels, return_inverse=True)[1].reshape(-1)


def label_difference(x: np.ndarray, y: np.ndarray) -> int:
    """Detections whose label differs between ``x`` and ``y`` after the best one-to-one
    matching of their tracks (-1, unassigned, matches -1 only)."""
    if x.size == 0:
        return 0
    ux, ix = np.unique(x, return_inverse=True)
    uy, iy = np.unique(y, return_inverse=True)
    table = np.zeros((ux.size, uy.size))
    np.add.at(table, (ix, iy), 1)
    table[ux < 0, :] = 0
    table[:, uy < 0] = 0
    r, c = linear_sum_assignment(-table)
    both_unassigned = int(np.sum((x < 0) & (y < 0)))
    return int(x.size - table[r, c].sum() - both_unassigned)


def link_difference(d: Detections, x: np.ndarray, y: np.ndarray) -> int:
    """Links (consecutive detections of a track) in one labelling and not in the other."""
    a = set(zip(*(v.tolist() for v in link_pairs(d, x)), strict=True))
    b = set(zip(*(v.tolist() for v in link_pairs(d, y)), strict=True))
    return len(a ^ b)


def layer1_survival(
    layout: Layout, detections: Detections, n_targets: int, config: AssociatorConfig
) -> dict[str, int]:
    """Segments, segments with every sensor flagged, sensors kept and sensors, whole clusters
    and clusters of ``mlkm_robust``'s Layer 1 and error detection on ``detections``."""
    d = detections.subset(canonical_order(detections))
    p = estimate_params(layout, d).on_road(layout.positions, config.entries, config.exits)
    out = dict.fromkeys(('segments', 'all_flagged', 'kept', 'sensors', 'whole', 'clusters'), 0)
    for seg in segments(layout.n_sensors, config.segment_size):
        idx = np.flatnonzero(np.isin(d.sensor_index, seg))
        if idx.size == 0:
            continue
        s = d.subset(idx)
        labels, _ = kmeans_labels(
            np.column_stack([s.velocity, s.stamp]), n_targets, 'k-means++', config.seed
        )
        flagged = detect_errors(s.sensor_index, s.stamp, labels).flagged
        flagged = flagged | implausible_links(layout.positions, s, labels, p)
        sensors = {int(x) for x in np.unique(s.sensor_index)}
        out['segments'] += 1
        out['kept'] += len(sensors - flagged)
        out['sensors'] += len(sensors)
        out['all_flagged'] += not (sensors - flagged)
        for k in np.unique(labels):
            at = s.sensor_index[labels == k]
            out['clusters'] += 1
            out['whole'] += at.size == len(sensors) and np.unique(at).size == len(sensors)
    return out


def compare(ds: Dataset, config: AssociatorConfig) -> dict:
    """The figures of one dataset (module docstring)."""
    run = {}
    for name, method in (
        ('assignment', make_associator('assignment', config)),
        ('mlkm_robust', make_associator('mlkm_robust', config)),
        ('forward', ForwardAnchor(config)),
    ):
        run[name] = method.associate(ds.layout, ds.detections, ds.n_targets)
    a, r = run['assignment'], run['mlkm_robust']
    return {
        'detections': len(ds.detections),
        'acc_assignment': score(ds.detections, a).accuracy,
        'acc_robust': score(ds.detections, r).accuracy,
        'differ': label_difference(r, a),
        'links': link_difference(ds.detections, r, a),
        **layer1_survival(ds.layout, ds.detections, ds.n_targets, config),
        'forward': label_difference(run['forward'], a),
        'anchor': label_difference(r, run['forward']),
    }


def datasets(
    parts: tuple[str, ...], seeds: int
) -> Iterator[tuple[str, Dataset, AssociatorConfig]]:
    """(name, dataset, config) of the chosen parts, ``seeds`` datasets per cell."""
    config = AssociatorConfig()
    if 'ngsim' in parts:
        from mlkm_core.trajectories import read_trajectories
        from mlkm_experiments.bench import real

        traj = read_trajectories(real.DATA)
        for stations in real.STATIONS:
            for road in real.VARIANTS_ROAD:
                sets = real.datasets(traj, stations, road, list(range(1, seeds + 1)))
                for k, ds in enumerate(sets, 1):
                    tag = f'ngsim {stations:2d} {road:6s} #{k}'
                    yield f'{tag} time,speed', time_speed_only(ds), config
                    yield f'{tag} +lane,length', ds, config
    if 'sim' in parts:
        from mlkm_core.simulator import simulate
        from mlkm_experiments.bench.common import MODES, dataset_seed, sim_config

        for mode in MODES:
            for k in range(seeds):
                ds = simulate(sim_config(mode, 50, 20), dataset_seed(50, 20, k))
                yield f'sim {mode:7s} 50x20 #{k + 1}', ds, config
    if 'sumo' in parts:
        from mlkm_experiments.bench import sumo_data

        for scenario in SUMO_SCENARIOS:
            for measurement in sumo_data.MEASUREMENTS:
                for k in range(1, seeds + 1):
                    yield from _sumo(scenario, measurement, k)


def _sumo(
    scenario: str, measurement: str, seed: int
) -> Iterator[tuple[str, Dataset, AssociatorConfig]]:
    """The SUMO dataset the benchmark draws (``bench.sumo_data``), in both variants."""
    from mlkm_experiments.bench import sumo_data
    from mlkm_sumo.api import generate

    s = generate(
        scenario,
        SUMO_VEHICLES,
        SUMO_STATIONS,
        seed,
        measurement=sumo_data.measurement_config(measurement),
    )
    ds = Dataset(s.layout, s.detections, s.n_targets)
    if measurement == 'clutter':
        rng = np.random.default_rng([seed, SUMO_VEHICLES, SUMO_STATIONS])
        ds = sumo_data.add_false_alarms(s, SUMO_VEHICLES, sumo_data.FALSE_ALARMS_PER_VEHICLE, rng)
    ramps = s.road.ramps
    config = AssociatorConfig(
        entries=tuple(float(x.position) for x in ramps if x.kind == 'on'),
        exits=tuple(float(x.position) for x in ramps if x.kind == 'off'),
    )
    tag = f'sumo {scenario:9s} {measurement:7s} #{seed}'
    yield f'{tag} time,speed', time_speed_only(ds), config
    yield f'{tag} +lane,length', ds, config


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog='python -m mlkm_experiments.robust_links',
        description="mlkm_robust's tracks against assignment's, and what is left of Layer 1",
    )
    ap.add_argument('--parts', default=','.join(PARTS), help='comma-separated: ngsim,sim,sumo')
    ap.add_argument('--seeds', type=int, default=3, help='datasets per cell (default 3)')
    args = ap.parse_args(argv)
    parts = tuple(x for x in args.parts.split(',') if x)
    unknown = set(parts) - set(PARTS)
    if unknown or args.seeds < 1:
        ap.error(f'parts are {",".join(PARTS)} and --seeds >= 1')
    print(
        f'{"dataset":38s} {"det":>5s} {"assign %":>8s} {"robust %":>8s} {"differ":>6s} '
        f'{"links":>5s} {"whole":>7s} {"segs":>4s} {"allflag":>7s} {"kept":>7s} '
        f'{"forward":>7s} {"anchor":>6s}'
    )
    tot: Counter[str] = Counter()
    for name, ds, cfg in datasets(parts, args.seeds):
        r = compare(ds, cfg)
        print(
            f'{name:38s} {r["detections"]:5d} {100 * r["acc_assignment"]:8.2f} '
            f'{100 * r["acc_robust"]:8.2f} {r["differ"]:6d} {r["links"]:5d} '
            f'{r["whole"]:3d}/{r["clusters"]:<3d} '
            f'{r["segments"]:4d} {r["all_flagged"]:7d} {r["kept"]:3d}/{r["sensors"]:<3d} '
            f'{r["forward"]:7d} {r["anchor"]:6d}',
            flush=True,
        )
        tot.update({k: r[k] for k in SUMMED})
        tot.update(n=1, n_differ=int(r['differ'] > 0))
    print(
        f'total: {tot["n"]} datasets, mlkm_robust differs from assignment on {tot["n_differ"]} '
        f'({tot["differ"]} of {tot["detections"]} detections); whole clusters {tot["whole"]} of '
        f'{tot["clusters"]}; every sensor flagged in {tot["all_flagged"]} of {tot["segments"]} '
        'segments; without Layer 1 (forward): '
        f'{tot["forward"]} detections differ from assignment, {tot["anchor"]} from mlkm_robust'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
