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
2. **Memory** (``memory``): an hour of SUMO traffic, the resident set of the node and of its
   tracker process against the tracker's progress; see :mod:`.stream_memory`.
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
import statistics
import sys
import tempfile
import time
from pathlib import Path

from .common import Log
from .stream_graph import SENSORS, _num, _params, ingest_rate, run_graph
from .stream_lag import SIM_SEEDS, SUMO_SEEDS, run_lag
from .stream_memory import run_memory

#: name -> (arrival_rate [vehicles/s], real_time_factor, duration [s]): 20 x rate x rtf det/s
LATENCY_RUNS = {'100/s': (0.5, 10.0, 300.0), '1000/s': (1.0, 50.0, 1500.0)}
LATENCY_P95_MAX = 0.05  # [s]
THROUGHPUT_SOURCE = (1.0, 0.0, 3000.0)
REPEATS = 3
INGEST_RATIO_MIN = 0.7


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
