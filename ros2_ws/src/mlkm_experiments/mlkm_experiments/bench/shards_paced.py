"""Shards live over loopback DDS (``mlkm bench --only shards``, its ``paced`` run): the
highest detection rate one node, 2 and 4 shards sustain, the CPU of each shard, and the
hand-off latency.

The graph is what a user runs: ``road_sensors log_source`` replays a SUMO highway log
(``DATA``) paced by its ``real_time_factor``; one ``association_node`` in stream mode, or N
shards in their namespaces with ``track_merge``; every process a separate executable on
loopback DDS in a domain of its own. For each configuration the rates of ``RATES`` are run in
turn until one is not sustained; then the rate between the last sustained and the first
failed one (their geometric mean) is run once more.

A rate is **sustained** when, for every node: the detection→track latency p95 (the node's own
``stream.latency_p95``: arrival in its callback to the publication of the TrackArray that
answers it, over its last 10,000 detections) is at most 50 ms; the road's detections reached
it at no less than ``DELIVERY_MIN`` of the paced rate (a node that cannot take them slows the
reliable source down); and its window solves kept up, the commit lag when the source ended
being at most ``COMMIT_LAG_MAX`` of stamp time (``lag`` plus two solve intervals and the
reorder tolerance: a backlog that grows with the run exceeds it).

**CPU**: utime + stime of each node and its tracker process (``/proc``), from the first
detection to the end of the source, over that wall time: the cores the shard used.
**Hand-off latency**: a subscriber on /mlkm/handoff takes the arrival of the first offer of
each upstream track and of the continuation that takes it, while the source runs; the
difference, in wall seconds, is how long the track's identity stays open downstream (the
vehicle's travel through the margin and the commit lag, at the paced rate, plus the shards'
processing). Its transit is the message's arrival minus its ``header.stamp`` (the shard's
clock, the same host here). The run ends once every node flushed its quiet road, so that
every continuation is counted (``QUIET_FLUSH`` of wall time after the last detection).
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .common import Log
from .stream import LATENCY_P95_MAX
from .stream_graph import _num, _sample, descendants, ingest_rate

CONFIGS = (1, 2, 4)
#: Paced rates tried in turn [detections/s].
RATES = (150.0, 300.0, 600.0, 1200.0, 2400.0)
DATA = {'scenario': 'highway', 'stations': 40, 'duration': 900.0, 'seed': 1}
METHOD, LAG, SOLVE_INTERVAL, REORDER = 'multiframe', 30.0, 10.0, 1.0
DELIVERY_MIN = 0.9
#: [s] of quiet wall time after which the nodes flush the road once the source ended (the
#: run's end; the lag of stamps would be 30 s of waiting per run)
QUIET_FLUSH = 10.0


def commit_lag_max(lag: float = LAG) -> float:
    """[s] of stamp time: the largest commit lag a node that keeps up shows at ``lag``."""
    return lag + 2 * SOLVE_INTERVAL + REORDER


COMMIT_LAG_MAX = commit_lag_max()  # [s] of stamp time
RUN_TIMEOUT = 600.0  # [s] of wall time per run


def write_log(out_dir: Path, cache_dir: Path | None, data: dict = DATA) -> dict:
    """The SUMO road's detections (``data`` as ``DATA``) as the product's CSV and layout
    file."""
    from mlkm_core.csvout import write_detections
    from mlkm_core.layout_file import RoadLayout, write_layout_file
    from mlkm_sumo.api import generate

    ds = generate(
        data['scenario'], n_stations=data['stations'], seed=data['seed'],
        duration=data['duration'], cache_dir=cache_dir,
    )  # fmt: skip
    d = ds.detections
    write_detections(out_dir / 'log.csv', ds.layout, d)
    write_layout_file(out_dir / 'layout.yaml', RoadLayout(ds.layout, ds.road.lanes))
    return {
        'log': str(out_dir / 'log.csv'),
        'layout': str(out_dir / 'layout.yaml'),
        'detections': int(d.stamp.size),
        'span_s': float(d.stamp.max() - d.stamp.min()),
        'stations': int(ds.layout.n_sensors),
    }


def tree_cpu(pid: int) -> float:
    """utime + stime [s] of process ``pid`` and its descendants alive now."""
    tick = os.sysconf('SC_CLK_TCK')
    total = 0.0
    for p in (pid, *descendants(pid)):
        try:
            fields = Path(f'/proc/{p}/stat').read_text().rsplit(')', 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
        except (OSError, IndexError, ValueError):
            continue
    return total


def node_names(count: int) -> list[str]:
    if count == 1:
        return ['/association_node']
    return [f'/shard_{k}/association_node' for k in range(count)]


def start_nodes(graph, count: int, lag: float = LAG) -> dict[str, object]:
    """The association nodes (by node name) and, with shards, ``track_merge``."""
    common = [
        '-p', 'mode:=stream', '-p', f'stream_method:={METHOD}', '-p', f'lag:={lag}',
        '-p', f'quiet_flush:={min(QUIET_FLUSH, lag)}', '-p', 'diagnostics_period:=0.5',
    ]  # fmt: skip
    if count == 1:
        proc = graph.start('association_node', 'mlkm_assoc', 'association_node', '--ros-args',
                           *common)  # fmt: skip
        return {'/association_node': proc}
    procs = {}
    for k, name in enumerate(node_names(count)):
        procs[name] = graph.start(
            f'shard_{k}', 'mlkm_assoc', 'association_node', '--ros-args',
            '-r', f'__ns:=/shard_{k}', '-p', 'source_namespace:=/', *common,
            '-p', f'shard_count:={count}', '-p', f'shard_index:={k}',
        )  # fmt: skip
    procs['track_merge'] = graph.start('track_merge', 'mlkm_assoc', 'track_merge', '--ros-args',
                                       '-p', f'shard_count:={count}')  # fmt: skip
    return procs


class HandoffClock:
    """Arrival times of offers and continuations on /mlkm/handoff."""

    def __init__(self) -> None:
        self.offered: dict[int, float] = {}  # upstream track -> first offer's arrival [s]
        self.delays: list[float] = []  # [s] offer -> continuation
        self.transits: list[float] = []  # [s] header.stamp -> arrival
        # continuations after the source ended (decided at the quiet road's flush, QUIET_FLUSH
        # of wall time later): counted, their delay not timed
        self.source_ended = math.inf  # [s] time.time()
        self.late = 0

    def __call__(self, msg) -> None:
        now = time.time()
        self.transits.append(now - (msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9))
        for track in msg.offers:
            self.offered.setdefault(int(track.track_id), now)
        for up in msg.continued_ids:
            if now > self.source_ended:
                self.late += 1
            elif int(up) in self.offered:
                self.delays.append(now - self.offered[int(up)])

    @property
    def continued(self) -> int:
        return len(self.delays) + self.late


def run_rate(
    domain_id: int, log_dir: Path, files: dict, count: int, rate: float, lag: float = LAG
) -> dict:
    """One configuration at one paced rate, the nodes committing ``lag`` [s] behind."""
    from mlkm_core.shards.regions import split_road
    from mlkm_ros import qos
    from mlkm_ros.conversions import diagnostics_values
    from mlkm_ros.processes import Graph, ScoreCollector
    from road_sensor_msgs.msg import TrackHandoff

    rtf = rate * files['span_s'] / files['detections']
    n = files['stations']
    regions = split_road(n, count) if count > 1 else []
    subscriptions = sum(len(r.stations) for r in regions) if regions else n
    names = node_names(count)
    samples: dict[str, list[dict]] = {name: [] for name in names}
    values: dict[str, dict] = {}
    clock = HandoffClock()
    collector = ScoreCollector(domain_id, diagnostics=True)
    collector.node.create_subscription(
        TrackHandoff, qos.HANDOFF_TOPIC, clock, qos.HANDOFF_READER_QOS
    )
    cpu0: dict[str, float] = {}
    try:
        with Graph(domain_id, log_dir, echo=False) as graph:
            procs = start_nodes(graph, count, lag)
            src = graph.start(
                'log_source', 'road_sensors', 'log_source', '--ros-args',
                '-p', f'log:={files["log"]}', '-p', f'layout:={files["layout"]}',
                '-p', 'mode:=continuous', '-p', f'real_time_factor:={rtf:.6f}',
                '-p', f'wait_for_subscriptions:={subscriptions}', '-p', 'wait_timeout:=120.0',
            )  # fmt: skip
            state = {'t0': None, 't1': None, 'cpu': {}}

            def take() -> None:
                while collector.diagnostics:
                    msg = collector.diagnostics.pop(0)
                    for name in names:
                        v = diagnostics_values(msg, name)
                        if v is not None:
                            values[name] = v
                            samples[name].append(_sample(msg, v))
                if state['t0'] is None and any(int(v.get('received', 0)) for v in values.values()):
                    state['t0'] = time.monotonic()
                    cpu0.update({k: tree_cpu(p.pid) for k, p in procs.items()})

            def source_done() -> bool:
                take()
                return src.poll() is not None

            why = collector.spin_until(source_done, timeout=RUN_TIMEOUT, abort=graph.failed)
            if why or src.poll() != 0:
                raise RuntimeError(f'log_source did not finish: {why or graph.failed()}')
            state['t1'] = time.monotonic()
            clock.source_ended = time.time()
            cpu1 = {k: tree_cpu(p.pid) for k, p in procs.items()}
            at_end = {k: _num(v, 'stream.commit_lag') for k, v in values.items()}

            def flushed() -> bool:
                # every detection through the tracker and the quiet road flushed (QUIET_FLUSH of
                # wall time after the last one): every continuation is decided and counted
                take()
                return len(values) == count and all(
                    int(v.get('stream.pushed') or 0) >= int(v.get('accepted', 0))
                    and v.get('stream.working_set') == '0'
                    for v in values.values()
                )

            why = collector.spin_until(flushed, timeout=RUN_TIMEOUT, abort=graph.failed)
            if why:
                raise RuntimeError(f'the nodes did not flush: {why}; logs in {log_dir}')
    finally:
        collector.close()
    wall = (state['t1'] or 0.0) - (state['t0'] or 0.0)
    merge_cpu = cpu1.get('track_merge', 0.0) - cpu0.get('track_merge', 0.0)
    nodes = {}
    for name in names:
        v = values[name]
        received = int(v.get('received', 0))
        seen = ingest_rate(samples[name])
        road_rate = seen * files['detections'] / received if seen and received else None
        nodes[name] = {
            'received': received,
            'latency_p50': _num(v, 'stream.latency_p50'),
            'latency_p95': _num(v, 'stream.latency_p95'),
            'latency_parts_p95': {
                part: _num(v, f'stream.latency_{part}_p95')
                for part in ('queue', 'hold', 'tracker', 'publish')
            },
            'handoffs_received': int(v.get('shard.handoffs_received') or 0),
            'road_rate': road_rate,
            'commit_lag_at_end': at_end.get(name),
            'cpu_s': cpu1[name] - cpu0.get(name, 0.0),
            'cores': (cpu1[name] - cpu0.get(name, 0.0)) / wall if wall > 0 else None,
        }
    return {
        'shards': count,
        'rate': rate,
        'real_time_factor': rtf,
        'nodes': nodes,
        'wall_s': wall,
        'merge_cores': merge_cpu / wall if count > 1 and wall > 0 else None,
        'handoff_delay': _quantiles(clock.delays),
        'handoff_transit': _quantiles(clock.transits),
        'continued': clock.continued,
        'lag': lag,
        'sustained': sustained(nodes, rate, lag),
    }


def sustained(nodes: dict, rate: float, lag: float = LAG) -> bool:
    """Every node answered within the latency bound, took the paced rate and kept up (its
    commit lag at most ``commit_lag_max(lag)``)."""
    most = commit_lag_max(lag)
    for r in nodes.values():
        p95, got, behind = r['latency_p95'], r['road_rate'], r['commit_lag_at_end']
        if p95 is None or p95 > LATENCY_P95_MAX:
            return False
        if got is None or got < DELIVERY_MIN * rate:
            return False
        if behind is None or behind > most:
            return False
    return True


def _quantiles(x: list[float]) -> dict:
    if not x:
        return {'count': 0, 'p50': None, 'p95': None}
    a = np.asarray(x)
    return {'count': a.size, 'p50': float(np.median(a)), 'p95': float(np.quantile(a, 0.95))}


def highest(domain_id: int, log_dir: Path, files: dict, count: int, log: Log) -> dict:
    """The ladder of rates for one configuration, then one rate between."""
    runs = []

    def one(rate: float) -> dict:
        sub = log_dir / f'shards{count}_{rate:.0f}'
        try:
            r = run_rate(domain_id, sub, files, count, rate)
        except RuntimeError as exc:
            r = {'shards': count, 'rate': rate, 'sustained': False, 'error': str(exc)}
        runs.append(r)
        log(f'shards paced: {count} node(s) at {rate:.0f} det/s: {_brief(r)}')
        return r

    best, failed = None, None
    for rate in RATES:
        if one(rate)['sustained']:
            best = rate
        else:
            failed = rate
            break
    if best is not None and failed is not None:
        mid = math.sqrt(best * failed)
        if one(mid)['sustained']:
            best = mid
    return {'shards': count, 'highest_rate': best, 'runs': runs}


def _brief(r: dict) -> str:
    if 'error' in r:
        return f'failed: {r["error"]}'
    p95 = max(n['latency_p95'] or math.inf for n in r['nodes'].values())
    got = min(n['road_rate'] or 0.0 for n in r['nodes'].values())
    lag = max(n['commit_lag_at_end'] or math.inf for n in r['nodes'].values())
    cores = ', '.join(f'{n["cores"]:.2f}' for n in r['nodes'].values() if n['cores'])
    return (
        f'{"sustained" if r["sustained"] else "not sustained"} (p95 {1e3 * p95:.1f} ms, '
        f'delivered {got:.0f} det/s, commit lag {lag:.1f} s, cores {cores})'
    )


def run_paced(log: Log, quick: bool = False, cache_dir: Path | None = None) -> dict:
    from mlkm_ros.domains import domain

    log_dir = Path(tempfile.mkdtemp(prefix='mlkm_bench_shards_paced_'))
    files = write_log(log_dir, cache_dir)
    out: dict = {
        'data': DATA,
        'detections': files['detections'],
        'logs': str(log_dir),
        'load_average_1min_start': os.getloadavg()[0],
        'cpus': os.cpu_count(),
    }
    configs = CONFIGS[:2] if quick else CONFIGS
    with domain() as domain_id:
        out['configs'] = [highest(domain_id, log_dir, files, c, log) for c in configs]
    one = out['configs'][0]['highest_rate']
    for c in out['configs']:
        c['vs_one'] = c['highest_rate'] / one if one and c['highest_rate'] else None
    out['load_average_1min_end'] = os.getloadavg()[0]
    return out


if __name__ == '__main__':  # a run of its own: python -m mlkm_experiments.bench.shards_paced
    import json

    result = run_paced(lambda m: print(m, flush=True), quick='--quick' in sys.argv)
    print(json.dumps(result, indent=1, default=float))


def report_lines(paced: dict) -> list[str]:
    """The paced run's section of the bench README."""
    if not paced.get('configs'):
        return []
    d = paced['data']
    lines = [
        '### Paced over DDS',
        '',
        f'`log_source` replays the SUMO {d["scenario"]} ({d["stations"]} stations, '
        f'{d["duration"]:g} s, seed {d["seed"]}; {paced["detections"]} detections) at a paced '
        'rate into one node or N shards and `track_merge`, every process its own executable '
        f"on loopback DDS ({paced['cpus']} cores). Sustained: every node's latency p95 at most "
        f'{1e3 * LATENCY_P95_MAX:g} ms, the paced rate delivered ({100 * DELIVERY_MIN:g} %) '
        f'and a commit lag at most {COMMIT_LAG_MAX:g} s when the source ends. CPU, latency and '
        'hand-off figures are those of the highest sustained rate.',
        '',
        '| nodes | highest sustained rate [det/s] | vs one node | cores per node | latency '
        'p95 per node [ms] | hand-off delay p50 / p95 [s] | hand-off transit p50 / p95 [ms] |',
        '| --- | --- | --- | --- | --- | --- | --- |',
    ]
    for c in paced['configs']:
        best = c['highest_rate']
        run = next((r for r in c['runs'] if r['rate'] == best and 'nodes' in r), None)
        if run is None:
            lines.append(f'| {c["shards"]} | none of {RATES[0]:g}.. | - | - | - | - | - |')
            continue
        nodes = run['nodes'].values()
        hd, ht = run['handoff_delay'], run['handoff_transit']
        lines.append(
            f'| {c["shards"]} | {best:.0f} | {c["vs_one"]:.2f} | '
            f'{", ".join(f"{n['cores']:.2f}" for n in nodes)}'
            + (f' (merge {run["merge_cores"]:.2f})' if run.get('merge_cores') else '')
            + ' | '
            f'{", ".join(f"{1e3 * n['latency_p95']:.1f}" for n in nodes)} | '
            + (f'{hd["p50"]:.1f} / {hd["p95"]:.1f}' if hd['count'] else '-')
            + ' | '
            + (f'{1e3 * ht["p50"]:.1f} / {1e3 * ht["p95"]:.1f}' if ht['count'] else '-')
            + ' |'
        )
    return [*lines, '']
