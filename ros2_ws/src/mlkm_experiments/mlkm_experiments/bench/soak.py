"""Soak: the live graph over many small episodes, watching the nodes' memory.

``sensor_sim``, ``association_node`` and ``scorer_node`` run as separate processes (as in the
demo) for ``episodes`` episodes of ``targets`` x ``sensors``. The source is paced
(``real_time_factor`` 250: about half a second per episode) so that the graph runs in a steady
state: at real_time_factor 0 it runs hundreds of episodes ahead of the association, and the
scorer, which holds at most ``max_open_episodes`` (100) unscored episodes, drops the ground
truth of the oldest (counted and logged; those episodes are scored incomplete), so the run
would measure a backlog instead. The resident set (``VmRSS`` of ``/proc/<pid>/status``) of the
association and scorer nodes is sampled over the run; the part passes when the median RSS
over the last 10 % of the episodes is at most 10 % above the median over the 10 % after the
first 10 % (the warm-up), and when nothing was lost: every detection received and none
rejected by the association node, every episode scored with its complete ground truth.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from .common import Log

EPISODES, TARGETS, SENSORS = 500, 10, 5
REAL_TIME_FACTOR = 250.0
QUICK_EPISODES = 50
SAMPLE_PERIOD = 0.25  # [s]
WINDOW = 0.1  # share of the run in each of the two compared windows
GROWTH_LIMIT = 0.10  # largest allowed relative RSS growth
NODES = ('association_node', 'scorer_node')


def vm_rss(pid: int) -> int | None:
    """Resident set size of process ``pid`` [bytes] (Linux); None when it is gone."""
    try:
        with open(f'/proc/{pid}/status') as f:
            for line in f:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1]) * 1024
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None


def rss_growth(progress, rss, window: float = WINDOW, limit: float = GROWTH_LIMIT) -> dict:
    """Compare the RSS after the warm-up (median over progress in [window, 2 window)) with the
    RSS at the end (median over progress >= 1 - window); ``progress`` runs from 0 to 1.
    ``ok`` is None when a window holds no sample."""
    p, r = np.asarray(progress, float), np.asarray(rss, float)
    early = r[(p >= window) & (p < 2 * window)]
    late = r[p >= 1 - window]
    if early.size == 0 or late.size == 0:
        return {'early_bytes': None, 'late_bytes': None, 'growth': None, 'ok': None}
    e, la = float(np.median(early)), float(np.median(late))
    growth = la / e - 1.0
    return {'early_bytes': e, 'late_bytes': la, 'growth': growth, 'ok': bool(growth <= limit)}


def _sim_args(episodes: int, targets: int, sensors: int, seed: int, rtf: float) -> list[str]:
    params = {
        'episodes': episodes,
        'seed': seed,
        'n_targets': targets,
        'n_sensors': sensors,
        'real_time_factor': float(rtf),
        'wait_for_subscribers': 1,
        'wait_for_truth_subscribers': 1,
    }
    args = ['--ros-args']
    for k, v in params.items():
        args += ['-p', f'{k}:={v}']
    return args


def run_soak(
    log: Log,
    episodes: int = EPISODES,
    targets: int = TARGETS,
    sensors: int = SENSORS,
    method: str = 'mlkm',
    seed: int = 0,
    real_time_factor: float = REAL_TIME_FACTOR,
    timeout: float = 1800.0,
) -> dict:
    from mlkm_ros.conversions import diagnostics_values
    from mlkm_ros.domains import domain
    from mlkm_ros.processes import Graph, ScoreCollector, start_association

    expected = episodes * targets * sensors
    log_dir = Path(tempfile.mkdtemp(prefix='mlkm_bench_soak_'))
    out: dict = {
        'scenario': {
            'episodes': episodes,
            'targets': targets,
            'sensors': sensors,
            'detections': expected,
            'method': method,
            'seed': seed,
            'real_time_factor': real_time_factor,
        },
        'sample_period_s': SAMPLE_PERIOD,
        'growth_limit': GROWTH_LIMIT,
        'logs': str(log_dir),
    }
    samples: list[dict] = []
    diag: dict[str, dict] = {}
    t_start = time.monotonic()
    with domain() as domain_id:
        collector = ScoreCollector(domain_id, diagnostics=True)
        try:
            with Graph(domain_id, log_dir, echo=False) as graph:
                start_association(graph, collector, method)
                pids = {n: graph.procs[n].proc.pid for n in NODES}
                graph.start(
                    'sensor_sim',
                    'road_sensors',
                    'sensor_sim',
                    *_sim_args(episodes, targets, sensors, seed, real_time_factor),
                )
                t0 = time.monotonic()
                due = t0

                def sample() -> None:
                    row = {'t': time.monotonic() - t0, 'episodes': len(collector.scores)}
                    row.update({n: vm_rss(pid) for n, pid in pids.items()})
                    samples.append(row)

                def drain() -> None:
                    while collector.diagnostics:
                        msg = collector.diagnostics.pop(0)
                        for n in NODES:
                            values = diagnostics_values(msg, f'/{n}')
                            if values is not None:
                                diag[n] = values

                def done() -> bool:
                    nonlocal due
                    drain()
                    if time.monotonic() >= due:
                        sample()
                        due += SAMPLE_PERIOD
                    return len(collector.scores) >= episodes

                why = collector.spin_until(done, timeout=timeout, abort=graph.failed)
                sample()
                out['seconds'] = time.monotonic() - t0
                # both nodes' diagnostics after the last episode
                collector.spin_until(lambda: drain() or _settled(diag, episodes), timeout=15.0)
                out['status'] = why or 'ok'
        finally:
            collector.close()
    log(f'soak: {len(collector.scores)} of {episodes} episodes scored ({out["status"]})')
    out['samples'] = samples
    _evaluate(out, collector.scores, diag, expected)
    out['wall_s'] = time.monotonic() - t_start
    return out


def _settled(diag: dict, episodes: int) -> bool:
    a, s = diag.get('association_node', {}), diag.get('scorer_node', {})
    scored = int(s.get('episodes_scored', 0)) + int(s.get('episodes_incomplete', 0))
    return a.get('episodes_published') == str(episodes) and scored >= episodes


def _evaluate(out: dict, scores: dict, diag: dict, expected: int) -> None:
    episodes = out['scenario']['episodes']
    samples = out['samples']
    progress = [s['episodes'] / episodes for s in samples]
    out['rss'] = {}
    for n in NODES:
        pts = [(p, s[n]) for p, s in zip(progress, samples) if s[n] is not None]
        out['rss'][n] = rss_growth([p for p, _ in pts], [r for _, r in pts])
    a = diag.get('association_node', {})
    totals = [int(s.total) for s in scores.values()]
    out['association_node'] = {
        k: a.get(k) for k in ('received', 'accepted', 'rejected', 'episodes_published')
    }
    complete = [s for s in scores.values() if s.truth_complete]
    out['scored'] = {
        'episodes': len(scores),
        'truth_complete': len(complete),
        'true_detections': sum(totals),
        'mean_accuracy': float(np.mean([s.accuracy for s in complete])) if complete else None,
    }
    sc = diag.get('scorer_node', {})
    out['scorer_node'] = {k: sc.get(k) for k in ('episodes_scored', 'episodes_incomplete')}
    # the scorer lists an event count once the event happened
    out['scorer_node']['episodes_dropped'] = sc.get('episodes_dropped', '0' if sc else None)
    out['nothing_lost'] = bool(
        out['status'] == 'ok'
        and a.get('received') == str(expected)
        and a.get('rejected') == '0'
        and len(scores) == episodes
        and out['scored']['truth_complete'] == episodes
        and sum(totals) == expected
    )
    rss_ok = [r['ok'] for r in out['rss'].values()]
    out['rss_ok'] = None if None in rss_ok else all(rss_ok)
    out['passed'] = bool(out['rss_ok'] and out['nothing_lost'])


def plot(out_dir: Path, soak: dict) -> str | None:
    """``soak.png``: RSS of each node over the episodes scored."""
    if not soak.get('samples'):
        return None
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for n in NODES:
        pts = [(s['episodes'], s[n] / 2**20) for s in soak['samples'] if s[n] is not None]
        if pts:
            ax.plot(*zip(*pts), '.-', ms=2, lw=1, label=n)
    sc = soak['scenario']
    e = sc['episodes']
    for x in (WINDOW * e, 2 * WINDOW * e, (1 - WINDOW) * e):
        ax.axvline(x, color='grey', ls=':', lw=1)
    ax.set_xlabel('episodes scored')
    ax.set_ylabel('resident set [MiB]')
    ax.set_title(
        f'Soak: {e} episodes of {sc["targets"]} targets x {sc["sensors"]} sensors, '
        f'method {sc["method"]}'
    )
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out_dir / 'soak.png', dpi=110)
    plt.close(fig)
    return 'soak.png'


def report_lines(soak: dict) -> list[str]:
    """The README section of the soak part."""
    L = ['## Soak', '']
    if not soak.get('samples'):
        return L + [str(soak.get('status', 'not run')), '']
    sc = soak['scenario']
    L += [
        f'`sensor_sim`, `association_node` and `scorer_node` as separate processes, '
        f'{sc["episodes"]} episodes of {sc["targets"]} targets x {sc["sensors"]} sensors '
        f'({sc["detections"]} detections) at real_time_factor {sc["real_time_factor"]:g} '
        f'(paced: the graph keeps up with the source), method `{sc["method"]}`, '
        f'{soak["seconds"]:.0f} s; resident set sampled every {soak["sample_period_s"]} s. '
        'Early: median over the episodes 10-20 % of the run; late: median over the last 10 %; '
        f'passes at a growth <= {100 * soak["growth_limit"]:.0f} %.',
        '',
        '| node | RSS early [MiB] | RSS late [MiB] | growth | pass |',
        '| --- | --- | --- | --- | --- |',
    ]
    for n, r in soak['rss'].items():
        if r['ok'] is None:
            L.append(f'| {n} | — | — | — | n/a |')
            continue
        L.append(
            f'| {n} | {r["early_bytes"] / 2**20:.1f} | {r["late_bytes"] / 2**20:.1f} | '
            f'{100 * r["growth"]:+.1f} % | {"yes" if r["ok"] else "**no**"} |'
        )
    a, s = soak['association_node'], soak['scored']
    L += [
        '',
        f'Nothing lost: {soak["nothing_lost"]} (association node received {a["received"]} of '
        f'{sc["detections"]} detections, rejected {a["rejected"]}; {s["episodes"]} episodes '
        f'scored, {s["truth_complete"]} with complete truth, {s["true_detections"]} true '
        f'detections scored); mean accuracy over the episodes with complete truth '
        f'{pct_or_na(s["mean_accuracy"])} %.',
        '',
        '![soak](soak.png)',
        '',
    ]
    return L


def pct_or_na(x: float | None) -> str:
    return 'n/a' if x is None else f'{100 * x:.2f}'
