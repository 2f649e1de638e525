"""Shards of a long road (``mlkm bench --only shards``): the association of N shards against
one tracker on the same detections, and each shard's tracker CPU.

Offline (``mlkm_core.shards.sharded``: the shards' trackers, hand-off desks and continuations
in one process, in a fixed order, which the multi-process test shows the live shards equal):
for 1, 2 and 4 shards, the accuracy, the difference to one tracker and where the differing
links lie (at a border: within the margin of one), the continuations across each border, and
the CPU each shard's tracker spent (``time.process_time``). The throughput figure is the one
these give when each shard has a core of its own: the detections over the busiest shard's
CPU, against one tracker's.

Live (:mod:`.shards_paced`): the highest paced rate one node, 2 and 4 shards sustain over
loopback DDS, each shard's CPU and the hand-off latency.

The border links: the true links from a detection in one shard to the next detection of
the same vehicle in the next shard, and how many of them the shards and one tracker get right
(what a hand-off has to carry; ``nothing lost at a border`` means the shards get as many).

Data: the SUMO highway in continuous traffic (3,000 vehicles/h, 5 km), 40 stations, seeds 1
and 2; the long SUMO highway (20 km, 200 stations, an hour of traffic; not with ``--quick``);
and the real NGSIM I-80 traffic through 20 virtual loops.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .common import Log
from .real import DATA as NGSIM
from .shards_paced import report_lines as paced_report
from .shards_paced import run_paced

COUNTS = (1, 2, 4)
SUMO = {'scenario': 'highway', 'stations': 40, 'duration': 1800.0, 'seeds': (1, 2)}
#: The long road: 20 km, 200 stations, an hour of traffic (about 600,000 detections).
LONG = {'scenario': 'long_highway', 'stations': 200, 'duration': 3600.0, 'seeds': (1,)}
METHOD, LAG = 'multiframe', 30.0


def _links(labels: np.ndarray, d) -> np.ndarray:
    """The detection each detection follows in its track (-1 first, -2 unassigned)."""
    out = np.full(labels.size, -2)
    last: dict[int, int] = {}
    for i in np.lexsort((d.stamp, d.sensor_index)).tolist():
        if labels[i] >= 0:
            out[i] = last.get(int(labels[i]), -1)
            last[int(labels[i])] = i
    return out


def _border_links(regions, truth: np.ndarray, d) -> np.ndarray:
    """The detections whose true predecessor lies in the shard upstream of their own: the
    links a hand-off has to carry over a border."""
    owner = np.empty(max(r.own[-1] for r in regions) + 1, np.int64)
    for r in regions:
        owner[list(r.own)] = r.index
    has = truth >= 0
    out = np.zeros(truth.size, bool)
    out[has] = owner[d.sensor_index[has]] != owner[d.sensor_index[truth[has]]]
    return np.nonzero(out)[0]


def compare(name: str, layout, d, log: Log) -> dict:
    """One dataset: one tracker, then every shard count."""
    from mlkm_core.metrics import accuracy
    from mlkm_core.shards.sharded import associate_sharded
    from mlkm_core.streaming import StreamConfig

    config = StreamConfig(method=METHOD, lag=LAG)
    truth = _links(d.target, d)
    rows = []
    one = None
    for n in COUNTS:
        t0 = time.monotonic()
        r = associate_sharded(layout, d, n, config)
        acc = accuracy(r.labels, d.target).accuracy
        links = _links(r.labels, d)
        if one is None:
            one = (acc, links, sum(r.seconds))
        crossing = _border_links(r.regions, truth, d)
        differ = np.nonzero(links != one[1])[0]
        near = np.zeros(differ.size, bool)
        for region in r.regions[1:]:
            lo, hi = region.margin[0], region.own[0] + len(region.margin)
            near |= (d.sensor_index[differ] >= lo) & (d.sensor_index[differ] < hi)
        rows.append({
            'shards': n,
            'accuracy': acc,
            'difference_points': 100 * (acc - one[0]),
            'links_differing': int(differ.size),
            'links_differing_at_a_border': int(near.sum()),
            'border_links': int(crossing.size),  # true links from one shard into the next
            'border_right': int((links[crossing] == truth[crossing]).sum()),
            'border_right_one': int((one[1][crossing] == truth[crossing]).sum()),
            'continued': r.accepted,
            'offered': r.offered,
            'pushed': r.pushed,
            'cpu_s': r.seconds,
            'speedup': one[2] / max(r.seconds),
            'wall_s': time.monotonic() - t0,
        })  # fmt: skip
        log(
            f'shards {name}: {n} shard(s) {100 * acc:.2f} % ({rows[-1]["difference_points"]:+.2f}'
            f' points, {differ.size} links differ, {int(near.sum())} at a border; border links '
            f'right {rows[-1]["border_right"]}/{crossing.size}, one tracker '
            f'{rows[-1]["border_right_one"]}), busiest '
            f'shard {max(r.seconds):.1f} s CPU of {one[2]:.1f} s'
        )
    return {'name': name, 'detections': int(d.stamp.size), 'rows': rows}


def compare_sumo(road: dict, seed: int, duration: float, log: Log, cache_dir=None) -> dict:
    """``compare`` on a SUMO road (``SUMO`` or ``LONG``) for one seed."""
    from mlkm_sumo.api import generate

    t0 = time.monotonic()
    sumo = generate(
        road['scenario'], n_stations=road['stations'], seed=seed, duration=duration,
        cache_dir=cache_dir,
    )  # fmt: skip
    log(f'shards: SUMO {road["scenario"]} seed {seed} in {time.monotonic() - t0:.0f} s')
    name = f'SUMO {road["scenario"]} {duration:g} s, {road["stations"]} stations, seed {seed}'
    return compare(name, sumo.layout, sumo.detections, log)


def run_shards(log: Log, quick: bool = False, cache_dir: Path | None = None) -> dict:
    from mlkm_core.loops import even_positions, virtual_loops
    from mlkm_core.trajectories import read_trajectories

    out = []
    traj = read_trajectories(NGSIM)
    ds = virtual_loops(traj, even_positions(20, 50, 450), closed=False).dataset
    out.append(compare('NGSIM I-80, 20 loops', ds.layout, ds.detections, log))
    for road in (SUMO,) if quick else (SUMO, LONG):
        duration = 600.0 if quick else road['duration']
        for seed in road['seeds'][:1] if quick else road['seeds']:
            out.append(compare_sumo(road, seed, duration, log, cache_dir))
    result = {'datasets': out, 'method': METHOD, 'lag': LAG}
    try:
        result['paced'] = run_paced(log, quick, cache_dir)
    except Exception as exc:  # noqa: BLE001 - the offline comparison stands on its own
        result['paced'] = {'status': f'failed: {exc}'}
    return result


def report_lines(shards: dict) -> list[str]:
    """The part's section of the bench README."""
    if not shards.get('datasets'):
        return []
    lines = [
        '## Shards (`--only shards`)',
        '',
        f'One long road split over N shards ({shards["method"]}, lag {shards["lag"]:g} s), '
        'offline: accuracy, the difference to one tracker, the links that differ (and how many '
        'lie at a border), continuations per border, and the CPU of the busiest shard against '
        "one tracker's (the speed-up with a core per shard). Border links: the true links "
        'from one shard into the next, and how many the shards (one tracker) got right.',
        '',
        '| data | shards | accuracy | vs one [points] | links differ (at a border) | '
        'border links right (one tracker) | continued per border | busiest shard CPU [s] | '
        'speed-up |',
        '| --- | --- | --- | --- | --- | --- | --- | --- | --- |',
    ]
    for ds in shards['datasets']:
        for r in ds['rows']:
            lines.append(
                f'| {ds["name"]} | {r["shards"]} | {100 * r["accuracy"]:.2f} % | '
                f'{r["difference_points"]:+.2f} | {r["links_differing"]} '
                f'({r["links_differing_at_a_border"]}) | '
                + (
                    f'{r["border_right"]} of {r["border_links"]} ({r["border_right_one"]}) | '
                    if 'border_links' in r
                    else '- | '
                )
                + f'{", ".join(str(c) for c in r["continued"][1:]) or "-"} | '
                f'{max(r["cpu_s"]):.1f} | {r["speedup"]:.2f} |'
            )
    return [*lines, '', *paced_report(shards.get('paced', {}))]


if __name__ == '__main__':  # one road alone: python -m mlkm_experiments.bench.shards long 1
    import json
    import sys

    which = {'highway': SUMO, 'long': LONG}[sys.argv[1]]
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else which['seeds'][0]
    row = compare_sumo(which, seed, which['duration'], lambda m: print(m, flush=True))
    print(json.dumps(row, indent=1, default=float))
