"""The stream bench's memory part (``memory`` of ``mlkm bench --only stream``): an hour of
SUMO ``highway`` (3,000 vehicles/h, 20 stations) through ``association_node`` in stream mode,
the resident set (VmRSS) of the node and of its tracker process sampled every second.

The source is paced (``MEMORY_RTF``) so that the window solves keep up: at real_time_factor 0
the node takes the hour in under a minute and the tracker then works through a backlog of
most of it, so the resident set would show the backlog, not how memory behaves on a road that
stays open. The run's progress is the tracker's: its committed stamp time, from the first
commit to the last. The part passes when the median over the last sixth of the progress is at
most ``soak.GROWTH_LIMIT`` above the median over the second sixth (after the warm-up) and nothing
is lost: the node received every detection the source published, each accepted or counted as
rejected, every accepted one pushed through the tracker and, after the quiet-road flush, none
left in its working set. A 10-minute probe runs first; the hour runs when the probe
extrapolates to at most ``HOUR_BUDGET`` of wall time, else the probe is the measurement.
"""

from __future__ import annotations

from pathlib import Path

from .common import Log
from .soak import rss_growth
from .stream_graph import SENSORS, _params, run_graph

PROBE_DURATION, HOUR = 600.0, 3600.0
HOUR_BUDGET = 1200.0  # [s] of wall time (the pace alone takes 720 s)
#: pace of the source: the hour in 12 min, within what the window solves take on the 2-core
#: machine (alone they work through the hour in about 6.5 min) [-]
MEMORY_RTF = 5.0
RSS_WINDOW = 1 / 6


def sumo_source(duration: float, seed: int = 1) -> tuple[str, ...]:
    p = {
        'mode': 'continuous',
        'scenario': 'highway',
        'stations': SENSORS,
        'duration': duration,
        'seed': seed,
        'real_time_factor': MEMORY_RTF,
        'wait_for_subscribers': 1,
    }
    return ('sumo_sensors', 'road_sensors', 'sumo_sensors', '--ros-args', *_params(p))


def tracker_progress(samples: list[dict]) -> list[float] | None:
    """Each sample's progress of the tracker through the run, from 0 to 1: its committed stamp
    time (``committed`` [s]) from the first commit to the last; 0 before the first commit.
    None when the samples hold fewer than two commit times."""
    done = [s['committed'] for s in samples if s.get('committed') is not None]
    if not done or max(done) <= min(done):
        return None
    c0, c1 = min(done), max(done)
    return [
        0.0 if s.get('committed') is None else (s['committed'] - c0) / (c1 - c0) for s in samples
    ]


def memory_verdict(rss_samples: list[dict], values: dict, published: int | None) -> dict:
    """RSS growth (node, tracker process, their sum) over the tracker's progress, the largest
    working set (whether the window solves kept up with the source), and nothing lost."""
    pts = [s for s in rss_samples if s['node'] is not None]
    prog = tracker_progress(pts)
    out: dict = {}
    if prog is not None:
        total = [s['node'] + (s['tracker'] or 0) for s in pts]
        out['rss_total'] = rss_growth(prog, total, RSS_WINDOW)
        out['rss_node'] = rss_growth(prog, [s['node'] for s in pts], RSS_WINDOW)
        trk = [(p, s['tracker']) for p, s in zip(prog, pts, strict=True) if s['tracker']]
        out['rss_tracker'] = rss_growth(*zip(*trk), RSS_WINDOW) if trk else None
    out['working_set_max'] = max((s.get('working_set') or 0 for s in pts), default=0)
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
        f'real_time_factor {MEMORY_RTF:g}',
        'duration': duration,
        'probe': {'duration': PROBE_DURATION, 'wall_s': probe['wall_s'], 'hour_estimate_s': est},
        'wall_s': run['wall_s'],
        'samples': run['rss'],
        'values': {k: v for k, v in run['values'].items() if k.startswith(('stream.', 'rej'))},
    }
    out.update(memory_verdict(run['rss'], run['values'], run['source_published']))
    return out


if __name__ == '__main__':  # the part alone: python -m mlkm_experiments.bench.stream_memory
    import json
    import sys
    import tempfile

    from mlkm_ros.domains import domain

    with domain() as domain_id:
        logs = Path(tempfile.mkdtemp(prefix='mlkm_bench_memory_'))
        result = run_memory(domain_id, logs, lambda m: print(m, flush=True), '--quick' in sys.argv)
    result.pop('samples')
    print(json.dumps(result, indent=1, default=float))
