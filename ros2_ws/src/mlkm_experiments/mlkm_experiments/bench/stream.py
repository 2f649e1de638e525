"""Stream mode on the open road (``mlkm bench --only stream``): latency, memory, throughput,
and accuracy against the commit lag.

Real executables over loopback DDS in a domain of their own; ``association_node`` with
``mode:=stream`` (its default method and lag), /diagnostics every 0.5 s.

1. **Latency** (``latency``): ``sensor_sim`` in continuous mode (paper model, 20 sensors,
   Poisson arrivals) paced by ``real_time_factor`` at about 100 and about 1,000
   detections/s. The figures are the node's own ``stream.latency_p50/p95/p99``: for every
   detection, from its arrival in the node's callback (monotonic clock) to the publication of
   the TrackArray answering the batch that held it (reorder buffer, tracker process and
   publish included), over the last 10,000 detections. The rate actually delivered is
   measured from the node's ``received`` counter.
2. **Memory** (``memory``): ``sumo_sensors`` continuous on SUMO ``highway`` (3,000
   vehicles/h, 20 stations) at real_time_factor 0. The resident set (VmRSS) of the node and of
   its tracker process is sampled every second; the part passes when the median over the last
   sixth of the run is at most 10 % above the median over the second sixth (after the
   warm-up; the run's progress is the share of its detections the tracker has taken,
   proportional to simulated time at the scenario's constant demand), and when nothing is
   lost: the node received every detection the source published, each accepted or counted as
   rejected, every accepted one pushed through the tracker and, after the quiet-road flush,
   none left in its working set.
   A 10-minute probe runs first; the simulated hour runs when the probe extrapolates to at
   most ``HOUR_BUDGET`` of wall time, else the probe is the measurement.
3. **Throughput** (``throughput``): ``sensor_sim`` continuous at real_time_factor 0 into a
   bare rclpy subscriber (counts only) and into the node, interleaved ``REPEATS`` times;
   rate = detections / (last arrival - first arrival). The node's arrival times come from
   its /diagnostics (``received`` with the message stamp, the last arrival from
   ``stream.idle``), so its rate is measured from the first diagnostics sample on. The source
   (60,000 detections, 6-10 s at these rates) is long enough for the steady state to dominate:
   with 10,000 detections the start-up and the 0.5 s diagnostics period made single runs of
   the same graph differ by up to 40 %.
4. **Accuracy against the lag** (``lag``): offline, see :mod:`.stream_lag`.
"""

from __future__ import annotations

import json
import os
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

from .common import Log
from .soak import rss_growth, vm_rss
from .stream_lag import SIM_SEEDS, SUMO_SEEDS, run_lag

SENSORS = 20
#: name -> (arrival_rate [vehicles/s], real_time_factor, duration [s]): 20 x rate x rtf det/s
LATENCY_RUNS = {'100/s': (0.5, 10.0, 300.0), '1000/s': (1.0, 50.0, 1500.0)}
LATENCY_P95_MAX = 0.05  # [s]
THROUGHPUT_SOURCE = (1.0, 0.0, 3000.0)
REPEATS = 3
INGEST_RATIO_MIN = 0.7
PROBE_DURATION, HOUR = 600.0, 3600.0
HOUR_BUDGET = 900.0  # [s] of wall time
RSS_WINDOW = 1 / 6
GROWTH_LIMIT = 0.10
SAMPLE_PERIOD = 1.0  # [s] RSS samples
NODE = '/association_node'
PUBLISHED = re.compile(r'published (\d+) detections')


def sim_source(rate: float, rtf: float, duration: float, seed: int = 0) -> tuple[str, ...]:
    p = {
        'mode': 'continuous',
        'n_sensors': SENSORS,
        'arrival_rate': rate,
        'real_time_factor': rtf,
        'duration': duration,
        'seed': seed,
        'wait_for_subscribers': 1,
    }
    return ('sensor_sim', 'road_sensors', 'sensor_sim', '--ros-args', *_params(p))


def sumo_source(duration: float, seed: int = 1) -> tuple[str, ...]:
    p = {
        'mode': 'continuous',
        'scenario': 'highway',
        'stations': SENSORS,
        'duration': duration,
        'seed': seed,
        'real_time_factor': 0.0,
        'wait_for_subscribers': 1,
    }
    return ('sumo_sensors', 'road_sensors', 'sumo_sensors', '--ros-args', *_params(p))


def _params(p: dict) -> list[str]:
    out = []
    for k, v in p.items():
        out += ['-p', f'{k}:={float(v) if isinstance(v, float) else v}']
    return out


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` alive now (Linux /proc)."""
    kids, todo = [], [pid]
    while todo:
        p = todo.pop()
        for task in Path(f'/proc/{p}/task').glob('*/children'):
            try:
                found = [int(x) for x in task.read_text().split()]
            except (FileNotFoundError, ProcessLookupError, ValueError):
                continue
            kids += found
            todo += found
    return kids


def tree_rss(pid: int) -> dict[str, int | None]:
    """VmRSS of process ``pid`` and the sum over its descendants (the tracker process)."""
    child = [r for r in (vm_rss(k) for k in descendants(pid)) if r is not None]
    return {'node': vm_rss(pid), 'tracker': sum(child) if child else None}


def ingest_rate(samples: list[dict]) -> float | None:
    """Detections/s from /diagnostics samples (``t`` stamp [s], ``received``, ``idle`` [s]):
    from the first sample with a detection to the last arrival (stamp - idle of a sample
    holding the final count)."""
    got = [s for s in samples if s['received'] > 0]
    if len(got) < 2:
        return None
    first, final = got[0], max(s['received'] for s in got)
    last = next(s for s in got if s['received'] == final)
    t_last = last['t'] - (last['idle'] or 0.0)
    if final <= first['received'] or t_last <= first['t']:
        return None
    return (final - first['received']) / (t_last - first['t'])


def run_graph(
    domain_id: int,
    log_dir: Path,
    source: tuple[str, ...],
    flush: bool = False,
    rss: bool = False,
    drain: bool = True,
    timeout: float = 600.0,
) -> dict:
    """The association node in stream mode fed by ``source`` until the source is done and
    every accepted detection went through the tracker (with ``flush``: until the quiet road
    was flushed and the working set is empty; without ``drain``: until nothing arrived for
    2 s). Returns the node's last /diagnostics values,
    the diagnostics samples, the RSS samples and what the source says it published."""
    from mlkm_ros.conversions import diagnostics_values
    from mlkm_ros.processes import Graph, ScoreCollector

    collector = ScoreCollector(domain_id, diagnostics=True)
    state: dict[str, str] = {}
    samples: list[dict] = []
    rss_samples: list[dict] = []
    try:
        with Graph(domain_id, log_dir, echo=False) as graph:
            node = graph.start(
                'association_node',
                'mlkm_assoc',
                'association_node',
                '--ros-args',
                *_params({'mode': 'stream', 'diagnostics_period': 0.5}),
            )
            why = collector.spin_until(
                lambda: collector.node.count_publishers('/mlkm/tracks') >= 1,
                timeout=60.0,
                abort=graph.failed,
            )
            if why:
                raise RuntimeError(f'association node did not come up: {why}')
            src = graph.start(*source)
            t0 = time.monotonic()
            due = t0

            def done() -> bool:
                nonlocal due
                while collector.diagnostics:
                    msg = collector.diagnostics.pop(0)
                    values = diagnostics_values(msg, NODE)
                    if values is None:
                        continue
                    state.clear()
                    state.update(values)
                    samples.append(_sample(msg, values))
                now = time.monotonic()
                if rss and now >= due:
                    due += SAMPLE_PERIOD
                    last = samples[-1] if samples else {'received': 0, 'pushed': 0}
                    rss_samples.append(
                        {
                            't': now - t0,
                            'received': last['received'],
                            'pushed': last['pushed'],
                            **tree_rss(node.pid),
                        }
                    )
                if src.poll() is None or not state:
                    return False
                if not drain:
                    return float(state.get('stream.idle') or 0.0) > 2.0
                accepted = int(state.get('accepted', 0))
                through = int(state.get('stream.pushed') or 0) >= accepted
                return through and (not flush or state.get('stream.working_set') == '0')

            why = collector.spin_until(done, timeout=timeout, abort=graph.failed)
            wall = time.monotonic() - t0
            if why:
                raise RuntimeError(f'stream run incomplete: {why}; log dir {log_dir}')
            found = PUBLISHED.findall(src.output())
            return {
                'values': dict(state),
                'samples': samples,
                'rss': rss_samples,
                'source_published': int(found[-1]) if found else None,
                'source_exit': src.poll(),
                'wall_s': wall,
            }
    finally:
        collector.close()


def _sample(msg, values: dict[str, str]) -> dict:
    t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
    idle = values.get('stream.idle') or None
    return {
        't': t,
        'received': int(values.get('received', 0)),
        'pushed': int(values.get('stream.pushed') or 0),
        'idle': None if idle is None else float(idle),
    }


def _num(values: dict, key: str) -> float | None:
    v = values.get(key)
    return None if v in (None, '') else float(v)


def run_latency(domain_id: int, log_dir: Path) -> dict:
    out = {}
    for name, (rate, rtf, duration) in LATENCY_RUNS.items():
        r = run_graph(domain_id, log_dir / f'latency_{name[:-2]}', sim_source(rate, rtf, duration))
        v = r['values']
        rec = {
            'arrival_rate': rate,
            'real_time_factor': rtf,
            'duration': duration,
            'nominal_rate': SENSORS * rate * rtf,
            'delivered_rate': ingest_rate(r['samples']),
            'received': int(v['received']),
            'rejected': int(v['rejected']),
            'latency_count': int(v['stream.latency_count']),
            'solve_time_mean': _num(v, 'stream.solve_time_mean'),
            'solve_time_max': _num(v, 'stream.solve_time_max'),
        }
        for q in ('p50', 'p95', 'p99', 'max'):
            rec[f'latency_{q}'] = _num(v, f'stream.latency_{q}')
        rec['latency_parts'] = {
            part: {q: _num(v, f'stream.latency_{part}_{q}') for q in ('p50', 'p95')}
            for part in ('queue', 'hold', 'tracker', 'publish')
        }
        rec['reorder_timeouts'] = _num(v, 'stream.reorder_timeouts')
        # how far the window solves were behind when the source stopped [s of stamp time]
        rec['commit_lag_at_end'] = _num(v, 'stream.commit_lag')
        rec['working_set_at_end'] = _num(v, 'stream.working_set')
        rec['ok'] = latency_ok(rec['latency_p95'])
        out[name] = rec
    return out


def latency_ok(p95: float | None, limit: float = LATENCY_P95_MAX) -> bool | None:
    return None if p95 is None else bool(p95 <= limit)


def memory_verdict(rss_samples: list[dict], values: dict, published: int | None) -> dict:
    """RSS growth (node + tracker process) over the run's progress, the share of the
    detections the tracker had taken (constant demand: proportional to simulated time; at
    real_time_factor 0 the node receives everything long before the tracker is through), and
    nothing lost."""
    final = int(values.get('stream.pushed') or 0)
    pts = [s for s in rss_samples if s['node'] is not None]
    out: dict = {}
    if pts and final > 0:
        prog = [s['pushed'] / final for s in pts]
        total = [s['node'] + (s['tracker'] or 0) for s in pts]
        out['rss_total'] = rss_growth(prog, total, RSS_WINDOW, GROWTH_LIMIT)
        out['rss_node'] = rss_growth(prog, [s['node'] for s in pts], RSS_WINDOW, GROWTH_LIMIT)
        trk = [(p, s['tracker']) for p, s in zip(prog, pts, strict=True) if s['tracker']]
        out['rss_tracker'] = rss_growth(*zip(*trk), RSS_WINDOW, GROWTH_LIMIT) if trk else None
    received, accepted = int(values.get('received', 0)), int(values.get('accepted', 0))
    rejected = int(values.get('rejected', 0))
    out['counts'] = {
        'source_published': published,
        'received': received,
        'accepted': accepted,
        'rejected': rejected,
        'pushed': int(values.get('stream.pushed') or 0),
        'working_set': int(values.get('stream.working_set') or 0),
        'tracks_final': int(values.get('stream.tracks_final') or 0),
    }
    c = out['counts']
    out['nothing_lost'] = bool(
        published is not None
        and received == published
        and accepted + rejected == received
        and c['pushed'] == accepted
        and c['working_set'] == 0
    )
    out['rss_ok'] = out.get('rss_total', {}).get('ok')
    out['ok'] = bool(out['rss_ok'] and out['nothing_lost'])
    return out


def run_memory(domain_id: int, log_dir: Path, log: Log, quick: bool) -> dict:
    probe = run_graph(
        domain_id,
        log_dir / 'memory_probe',
        sumo_source(PROBE_DURATION),
        flush=True,
        rss=True,
        timeout=1800.0,
    )
    est = probe['wall_s'] * HOUR / PROBE_DURATION
    log(f'stream memory: {PROBE_DURATION:g} simulated s took {probe["wall_s"]:.0f} s wall')
    run, duration = probe, PROBE_DURATION
    if not quick and est <= HOUR_BUDGET:
        run = run_graph(
            domain_id, log_dir / 'memory', sumo_source(HOUR), flush=True, rss=True, timeout=3 * est
        )
        duration = HOUR
    out = {
        'scenario': f'SUMO highway (3,000 vehicles/h), {SENSORS} stations, seed 1, '
        'real_time_factor 0',
        'duration': duration,
        'probe': {'duration': PROBE_DURATION, 'wall_s': probe['wall_s'], 'hour_estimate_s': est},
        'wall_s': run['wall_s'],
        'samples': run['rss'],
        'values': {k: v for k, v in run['values'].items() if k.startswith(('stream.', 'rej'))},
    }
    out.update(memory_verdict(run['rss'], run['values'], run['source_published']))
    return out


def run_throughput(domain_id: int, log_dir: Path) -> dict:
    from mlkm_ros.processes import Graph

    bares, assocs = [], []
    for i in range(REPEATS):
        with Graph(domain_id, log_dir / f'bare{i}', echo=False) as graph:
            bare = graph.start_argv(
                'bare', sys.executable, '-m', 'mlkm_experiments.bench.stream_bare'
            )
            src = graph.start(*sim_source(*THROUGHPUT_SOURCE))
            if bare.wait(300.0) is None:
                raise RuntimeError(f'bare subscriber did not finish; log {bare.log_path}')
            src.wait(30.0)
            lines = [ln for ln in bare.output().splitlines() if ln.startswith('{')]
            if not lines:
                raise RuntimeError(f'bare subscriber printed no result; log {bare.log_path}')
            bares.append(json.loads(lines[-1]))
        r = run_graph(
            domain_id, log_dir / f'assoc{i}', sim_source(*THROUGHPUT_SOURCE), drain=False
        )
        assocs.append(
            {'ingest_rate': ingest_rate(r['samples']), 'received': r['values']['received']}
        )
    b = statistics.median(x['ingest_rate'] for x in bares)
    a = statistics.median(x['ingest_rate'] or 0.0 for x in assocs)
    return {
        'source': 'sensor_sim continuous, {} sensors, {} vehicles/s, real_time_factor 0, '
        '{:g} s'.format(SENSORS, *THROUGHPUT_SOURCE[::2]),
        'bare': bares,
        'association': assocs,
        'bare_rate': b,
        'association_rate': a,
        'ratio': a / b if b else None,
        'ok': bool(b and a / b >= INGEST_RATIO_MIN),
    }


def run_stream(log: Log, quick: bool = False, cache_dir: Path | None = None) -> dict:
    from mlkm_ros.domains import domain

    log_dir = Path(tempfile.mkdtemp(prefix='mlkm_bench_stream_'))
    out: dict = {'logs': str(log_dir), 'load_average_1min_start': os.getloadavg()[0]}
    with domain() as domain_id:
        for name, fn in (
            ('latency', lambda: run_latency(domain_id, log_dir)),
            ('throughput', lambda: run_throughput(domain_id, log_dir)),
            ('memory', lambda: run_memory(domain_id, log_dir, log, quick)),
            (
                'lag',
                lambda: run_lag(
                    log,
                    cache_dir,
                    sim_seeds=(0, 1) if quick else SIM_SEEDS,
                    sumo_seeds=(1,) if quick else SUMO_SEEDS,
                ),
            ),
        ):
            t = time.monotonic()
            try:
                out[name] = fn()
            except Exception as exc:  # noqa: BLE001 - one broken measurement keeps the others
                out[name] = {'status': f'failed: {exc}'}
            out.setdefault('runs', {})[name] = {
                'wall_s': time.monotonic() - t,
                'load_average_1min': os.getloadavg()[0],
            }
            log(f'stream {name}: {time.monotonic() - t:.0f} s: {_brief(name, out[name])}')
    out['load_average_1min_end'] = os.getloadavg()[0]
    out['status'] = 'ok'
    return out


def _brief(name: str, r: dict) -> str:
    if 'status' in r and r['status'] != 'ok':
        return r['status']
    if name == 'latency':
        return '; '.join(
            f'{k}: p50/p95/p99 {v["latency_p50"]}/{v["latency_p95"]}/{v["latency_p99"]} s'
            for k, v in r.items()
        )
    if name == 'throughput':
        return f'ratio {r["ratio"]:.2f}'
    if name == 'memory':
        return f'rss {r.get("rss_total")}, nothing lost {r["nothing_lost"]}'
    return ', '.join(f'{f}: ok {v["ok"]}' for f, v in r.get('families', {}).items())
