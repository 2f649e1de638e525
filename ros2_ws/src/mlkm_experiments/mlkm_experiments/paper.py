"""Reproduce the paper's experiments: Figures 3, 4 and 8 and Table III (``mlkm paper``).

Every dataset is ``simulate(config, seed)`` with seeds 0..N-1 and the default simulator; every
associator runs with ``AssociatorConfig(segment_size=K, seed=seed)``. Accuracy is the contract's
``mlkm_core.metrics.accuracy``. Outputs in ``out``: PNG bar charts (minimum, mean, maximum per
method, as the paper draws them), ``accuracies.csv`` (one row per dataset and method) and
``results.md`` (our figures beside the paper's, the checks against the paper and the wall
time). ``mlkm paper`` exits 1 when a check does not hold.
"""

from __future__ import annotations

import csv
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mlkm_core.associators import make_associator
from mlkm_core.associators.base import AssociatorConfig
from mlkm_core.associators.dnn import LEARNING_RATE, MAX_ITER, dnn_split
from mlkm_core.metrics import accuracy
from mlkm_core.simulator import SimConfig, simulate

#: Set (unless the user set them) for the worker processes of a run: each worker gets one
#: BLAS/OpenMP thread, the machine's cores go to the process pool.
WORKER_THREADS = ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')

SIM1 = SimConfig(n_targets=10, n_sensors=10)
SIM2 = SimConfig(n_targets=50, n_sensors=20)
SIM_DNN = SimConfig(n_targets=50, n_sensors=50)
KMEANS_METHODS = [
    ('kmeans_up', 'UP: K-means'),
    ('kmeans_pp_up', 'UP: K-means++'),
    ('kmeans_p', 'P: K-means'),
    ('kmeans_pp', 'P: K-means++'),
]
MLKM_METHODS = [
    ('kmeans_pp', 'P: K-means++'),
    ('mlkm_no_ec', 'MLKM w/o EC'),
    ('mlkm', 'MLKM w/ EC'),
]
DNN_SPLITS = [20, 25, 30, 40, 45]  # training sensors out of 50
PAPER_DNN = {
    20: (98.0, 68.0),
    25: (97.8, 68.0),
    30: (99.0, 72.0),
    40: (98.6, 84.4),
    45: (98.9, 91.6),
}  # train, test accuracy [%]
PAPER_FIG8 = {'mlkm_no_ec': 84.3, 'mlkm': 91.65}  # mean accuracy [%], Section IV-3


@dataclass(frozen=True)
class Task:
    kind: str  # 'sim1', 'sim2' or 'dnn'
    seed: int
    n_train: int = 0


def _run_task(task: Task, segment_size: int) -> list[tuple[str, str, int, float, float]]:
    """(experiment, method, seed, accuracy, extra) rows for one dataset."""
    if task.kind == 'dnn':
        r = dnn_split(simulate(SIM_DNN, task.seed), task.n_train, task.seed)
        return [('dnn', str(task.n_train), task.seed, r.test_accuracy, r.train_accuracy)]
    config = SIM1 if task.kind == 'sim1' else SIM2
    ds = simulate(config, task.seed)
    methods = {m for m, _ in KMEANS_METHODS}
    if task.kind == 'sim2':
        methods |= {m for m, _ in MLKM_METHODS}
    cfg = AssociatorConfig(segment_size=segment_size, seed=task.seed)
    rows = []
    for m in sorted(methods):
        labels = make_associator(m, cfg).associate(ds.layout, ds.detections, ds.n_targets)
        rows.append(
            (
                task.kind,
                m,
                task.seed,
                accuracy(labels, ds.detections.target).accuracy,
                float('nan'),
            )
        )
    return rows


def _stats(values: list[float]) -> tuple[float, float, float]:
    a = 100.0 * np.asarray(values)
    return float(a.min()), float(a.mean()), float(a.max())


def _bar_chart(
    path: Path,
    title: str,
    labels: list[str],
    stats: list[tuple[float, ...]],
    ylabel: str = 'accuracy [%]',
) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    x = np.arange(len(labels))
    width = 0.27
    fig, ax = plt.subplots(figsize=(1.6 * len(labels) + 2.5, 3.6))
    for i, (name, color) in enumerate(
        [('minimum', '#4472c4'), ('mean', '#ed7d31'), ('maximum', '#a5a5a5')]
    ):
        vals = [s[i] for s in stats]
        bars = ax.bar(x + (i - 1) * width, vals, width, label=name, color=color)
        ax.bar_label(bars, fmt='%.1f', fontsize=7, padding=1)
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylim(0, 112)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc='upper center', bbox_to_anchor=(0.5, -0.12), ncol=3, frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


@contextmanager
def one_thread_workers() -> Iterator[None]:
    """``WORKER_THREADS`` = 1 where unset, for the duration; the environment is restored after."""
    added = [v for v in WORKER_THREADS if v not in os.environ]
    for v in added:
        os.environ[v] = '1'
    try:
        yield
    finally:
        for v in added:
            os.environ.pop(v, None)


def run(
    n_datasets: int = 100,
    out: str | Path = 'results/paper',
    jobs: int = 2,
    dnn_datasets: int = 10,
    segment_size: int = AssociatorConfig.segment_size,
    progress: bool = True,
) -> dict:
    """Run every experiment, write figures, CSV and results.md; return the summary."""
    from joblib import Parallel, delayed
    from tqdm import tqdm

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tasks = [Task('dnn', s, n) for n in DNN_SPLITS for s in range(dnn_datasets)]
    tasks += [Task(kind, s) for kind in ('sim2', 'sim1') for s in range(n_datasets)]
    load_start = os.getloadavg()[0]
    start = time.perf_counter()
    rows: list[tuple[str, str, int, float, float]] = []
    with one_thread_workers():
        parallel = Parallel(n_jobs=jobs, return_as='generator_unordered')
        for part in tqdm(
            parallel(delayed(_run_task)(t, segment_size) for t in tasks),
            total=len(tasks),
            desc='mlkm paper',
            unit='dataset',
            disable=not progress,
        ):
            rows.extend(part)
    wall = time.perf_counter() - start
    rows.sort(key=lambda r: (r[0], r[1], r[2]))
    with open(out / 'accuracies.csv', 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(['experiment', 'method_or_train_sensors', 'seed', 'accuracy', 'train_accuracy'])
        for r in rows:
            w.writerow([r[0], r[1], r[2], f'{r[3]:.6f}', '' if np.isnan(r[4]) else f'{r[4]:.6f}'])

    def acc(kind: str, method: str) -> list[float]:
        return [r[3] for r in rows if r[0] == kind and r[1] == method]

    summary: dict = {
        'n_datasets': n_datasets,
        'dnn_datasets': dnn_datasets,
        'segment_size': segment_size,
        'wall_s': wall,
        'jobs': jobs,
        'load': (load_start, os.getloadavg()[0]),
        'cpus': os.cpu_count(),
    }
    for kind in ('sim1', 'sim2'):
        summary[kind] = {m: _stats(acc(kind, m)) for m, _ in KMEANS_METHODS}
    summary['fig8'] = {m: _stats(acc('sim2', m)) for m, _ in MLKM_METHODS}
    summary['dnn'] = {
        n: (
            _stats([r[4] for r in rows if r[0] == 'dnn' and r[1] == str(n)]),
            _stats(acc('dnn', str(n))),
        )
        for n in DNN_SPLITS
    }

    names = [n for _, n in KMEANS_METHODS]
    _bar_chart(
        out / 'fig3_sim1_kmeans.png',
        'Fig. 3: K-means / K-means++, Simulation 1 (10 targets, 10 sensors)',
        names,
        [summary['sim1'][m] for m, _ in KMEANS_METHODS],
    )
    _bar_chart(
        out / 'fig4_sim2_kmeans.png',
        'Fig. 4: K-means / K-means++, Simulation 2 (50 targets, 20 sensors)',
        names,
        [summary['sim2'][m] for m, _ in KMEANS_METHODS],
    )
    _bar_chart(
        out / 'fig8_mlkm.png',
        f'Fig. 8: MLKM (K = {segment_size}) vs K-means++ (P), 50 targets, 20 sensors',
        [n for _, n in MLKM_METHODS],
        [summary['fig8'][m] for m, _ in MLKM_METHODS],
    )
    _bar_chart(
        out / 'table3_dnn_test.png',
        'Table III: DNN test accuracy, 50 targets, 50 sensors',
        [f'{n}/{50 - n}' for n in DNN_SPLITS],
        [summary['dnn'][n][1] for n in DNN_SPLITS],
    )
    summary['checks'] = _checks(summary)
    (out / 'results.md').write_text(_markdown(summary))
    return summary


def _checks(s: dict) -> list[tuple[str, bool]]:
    mean = {k: {m: v[1] for m, v in s[k].items()} for k in ('sim1', 'sim2', 'fig8')}
    dnn_test = [s['dnn'][n][1][1] for n in DNN_SPLITS]
    checks = []
    for k, label in (('sim1', 'Simulation 1'), ('sim2', 'Simulation 2')):
        m = mean[k]
        checks.append((f'{label}: K-means(UP) < K-means(P)', m['kmeans_up'] < m['kmeans_p']))
        checks.append(
            (f'{label}: K-means++(UP) < K-means++(P)', m['kmeans_pp_up'] < m['kmeans_pp'])
        )
    checks.append(
        (
            'every K-means method lower in Simulation 2 than in Simulation 1',
            all(mean['sim2'][m] < mean['sim1'][m] for m, _ in KMEANS_METHODS),
        )
    )
    f8 = mean['fig8']
    checks.append(
        (
            '50/20: K-means++(P) < MLKM w/o EC < MLKM w/ EC',
            f8['kmeans_pp'] < f8['mlkm_no_ec'] < f8['mlkm'],
        )
    )
    checks.append(('MLKM w/ EC mean in [85, 98] %', 85.0 <= f8['mlkm'] <= 98.0))
    checks.append(('error correction adds >= 4 points', f8['mlkm'] - f8['mlkm_no_ec'] >= 4.0))
    checks.append(
        (
            'DNN test accuracy rises with the share of training sensors',
            all(a < b for a, b in zip(dnn_test, dnn_test[1:])),
        )
    )
    checks.append(('whole run under 10 minutes', s['wall_s'] < 600.0))
    return checks


def _fmt(t: tuple[float, float, float]) -> str:
    return f'{t[0]:.1f} / **{t[1]:.1f}** / {t[2]:.1f}'


def _markdown(s: dict) -> str:
    sim = SIM2
    lines = [
        "# Reproduction of the paper's experiments",
        '',
        'Generated by `mlkm paper` (`make experiments`); do not edit by hand.',
        f'{s["n_datasets"]} seeded datasets per configuration (seeds 0..{s["n_datasets"] - 1})'
        f' for Figures 3, 4 and 8; {s["dnn_datasets"]} per split for Table III '
        f'(MLPClassifier, full-batch Adam, learning rate {LEARNING_RATE}, at most {MAX_ITER} '
        'epochs; trained on the first sensors along the road, tested on the others). '
        f'MLKM segment size K = {s["segment_size"]}.',
        f'Wall time: {s["wall_s"]:.0f} s with {s["jobs"]} worker process(es) on {s["cpus"]} '
        f'CPUs (1-minute load average {s["load"][0]:.1f} at the start, {s["load"][1]:.1f} at '
        'the end; the machine is shared).',
        '',
        'Default simulator (`mlkm_core.simulator.SimConfig`): road length '
        f'{sim.road_length:g} m, cruise speed N({sim.velocity_mean:g}, {sim.velocity_std:.2f}^2)'
        f' m/s, start increments U({sim.start_increment_min:g}, {sim.start_increment_max:g}) s,'
        f' speed fluctuation (Ornstein-Uhlenbeck along the road) std '
        f'{sim.velocity_variation:g} m/s, correlation length {sim.variation_length:g} m.',
        '',
        "Cells are minimum / **mean** / maximum accuracy in %, as the paper's bar charts draw "
        'them (the paper gives Figures 3 and 4 only as charts, without numbers in the text).',
        '',
        '## Figures 3 and 4: K-means and K-means++ on unprocessed (UP) and preprocessed (P) data',
        '',
        '| method | Sim. 1 (10 targets, 10 sensors) | Sim. 2 (50 targets, 20 sensors) | paper |',
        '| --- | --- | --- | --- |',
    ]
    for m, name in KMEANS_METHODS:
        lines.append(
            f'| {name} | {_fmt(s["sim1"][m])} | {_fmt(s["sim2"][m])} | '
            'P above UP; Sim. 2 below Sim. 1 |'
        )
    lines += [
        '',
        '![Figure 3](fig3_sim1_kmeans.png)',
        '',
        '![Figure 4](fig4_sim2_kmeans.png)',
        '',
        '## Figure 8: MLKM with and without error correction (50 targets, 20 sensors)',
        '',
        '| method | ours | paper (mean) |',
        '| --- | --- | --- |',
    ]
    for m, name in MLKM_METHODS:
        paper = f'{PAPER_FIG8[m]:.2f}' if m in PAPER_FIG8 else 'below MLKM w/o EC'
        lines.append(f'| {name} | {_fmt(s["fig8"][m])} | {paper} |')
    f8 = s['fig8']
    lines += [
        '',
        f'Error correction adds {f8["mlkm"][1] - f8["mlkm_no_ec"][1]:.2f} points (paper: +7.35).',
        '',
        '![Figure 8](fig8_mlkm.png)',
        '',
        '## Table III: DNN, 50 targets, 50 sensors',
        '',
        '| train / test sensors | train acc. (ours) | test acc. (ours) | '
        'train acc. (paper) | test acc. (paper) |',
        '| --- | --- | --- | --- | --- |',
    ]
    for n in DNN_SPLITS:
        tr, te = s['dnn'][n]
        p_tr, p_te = PAPER_DNN[n]
        lines.append(f'| {n} / {50 - n} | {_fmt(tr)} | {_fmt(te)} | {p_tr:.1f} | {p_te:.1f} |')
    lines += ['', '![Table III](table3_dnn_test.png)', '', '## Checks against the paper', '']
    for text, ok in s['checks']:
        lines.append(f'- [{"x" if ok else " "}] {text}')
    lines.append('')
    return '\n'.join(lines)


def main_args(
    datasets: int, out: str, jobs: int, dnn_datasets: int | None, segment_size: int
) -> int:
    s = run(
        datasets,
        out,
        jobs,
        dnn_datasets if dnn_datasets is not None else min(datasets, 10),
        segment_size,
    )
    failed = [t for t, ok in s['checks'] if not ok]
    print(
        f'wrote {Path(out) / "results.md"} in {s["wall_s"]:.0f} s; '
        f'{len(s["checks"]) - len(failed)}/{len(s["checks"])} checks hold'
    )
    for t in failed:
        print(f'  check does not hold: {t}')
    return 1 if failed else 0
