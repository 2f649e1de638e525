"""``mlkm bench``: argument parsing and the order of the parts."""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
import time
import traceback
from pathlib import Path

from mlkm_core.associators import available_methods
from mlkm_core.cli_args import renamed_option

from . import (
    cost,
    grid,
    network,
    network_long,
    peer,
    real,
    shards,
    soak,
    stream,
    sumo,
    sumo_families,
)
from .plots import plot_all, plot_stream
from .report import write_readme
from .targets import evaluate_targets

#: Parts in the order they run: the ones that fork child processes come before the ones that
#: start DDS participants in this process (soak).
PARTS = ('grid', 'peer', 'cost', 'real', 'sumo', 'network', 'live', 'soak', 'stream', 'shards')


def _run_live(out_dir: Path, log) -> dict:
    # imported here: ``python -m mlkm_experiments.bench.live`` must not find the module
    # already imported by the package
    from .live import run_live

    return run_live(out_dir, log)


def _run_network(log, quick: bool, cache_dir) -> dict:
    """The network families and, in a full run, the hour-long inputs (``network_long``)."""
    out = network.run_network(log, quick, cache_dir)
    if not quick:
        out['long'] = network_long.run_long(log, cache_dir)
    return out


def _now() -> str:
    return dt.datetime.now(dt.UTC).strftime('%Y-%m-%d %H:%M UTC')


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    from . import __doc__ as doc

    ap = argparse.ArgumentParser(prog='mlkm bench', description=doc.splitlines()[0])
    renamed_option(
        ap, '--output', '--out', default='results/bench', help='output directory (results/bench)'
    )
    ap.add_argument('--quick', action='store_true', help='small smoke version')
    ap.add_argument(
        '--only',
        choices=PARTS,
        action='append',
        help='run only these parts (repeatable); default: all',
    )
    ap.add_argument('--methods', help='comma-separated subset of methods (default: all)')
    ap.add_argument(
        '--report-only',
        action='store_true',
        help='run nothing: rewrite README.md, summary.json and the plots from the JSON files',
    )
    ap.add_argument(
        '--real-data',
        type=Path,
        default=real.DATA,
        help=f'NGSIM trajectories of part real (default: {real.DATA})',
    )
    ap.add_argument(
        '--families-only',
        action='store_true',
        help='part sumo: run only the scenario families, keep the other cells of sumo.json',
    )
    ap.add_argument(
        '--keep-peer',
        action='store_true',
        help="part sumo: take the Stone Soup peer's rows of each cell from sumo.json instead "
        'of running it again (its input and code are not the product; each kept row says '
        'when it ran)',
    )
    ap.add_argument(
        '--cache-dir',
        type=Path,
        help='keep the generated SUMO datasets here (default: a temporary directory per run)',
    )
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    out_dir = Path(args.output)
    out_dir.mkdir(parents=True, exist_ok=True)
    parts = [] if args.report_only else [p for p in PARTS if p in set(args.only or PARTS)]
    methods = args.methods.split(',') if args.methods else available_methods()
    unknown = sorted(set(methods) - set(available_methods()))
    if unknown:
        print(f'mlkm bench: unknown method(s) {", ".join(unknown)}', file=sys.stderr)
        return 2
    t_start = time.monotonic()
    logf = open(out_dir / 'bench.log', 'a')

    def log(msg: str) -> None:
        line = f'[{time.monotonic() - t_start:7.1f} s] {msg}'
        print(line, flush=True)
        logf.write(line + '\n')
        logf.flush()

    def load(name: str) -> dict:
        f = out_dir / f'{name}.json'
        return json.loads(f.read_text()) if f.exists() else {}

    def save(name: str, data: dict) -> None:
        (out_dir / f'{name}.json').write_text(json.dumps(data, indent=1, default=float))

    quick = args.quick
    seeds = grid.SEEDS_QUICK if quick else grid.SEEDS_FULL
    runners = {
        'grid': lambda: grid.run_grid(methods, seeds, log),
        'peer': lambda: peer.run_peer(
            {c: 1 if quick else min(n, seeds[c]) for c, n in peer.PEER_SEEDS.items()}, log
        ),
        'cost': lambda: cost.run_cost(
            methods,
            cost.COST_TARGETS[:3] if quick else cost.COST_TARGETS,
            20.0 if quick else cost.COST_LIMIT,
            log,
        ),
        'real': lambda: real.run_real(
            methods, real.SEEDS_QUICK if quick else real.SEEDS_FULL, log, args.real_data
        ),
        'sumo': lambda: sumo.run_sumo(
            methods,
            sumo.SEEDS_QUICK if quick else sumo.SEEDS_FULL,
            log,
            args.cache_dir,
            families=sumo_families.plan(quick),
            previous=load('sumo') if args.families_only else None,
            peer_rows=sumo.peer_rows(load('sumo')) if args.keep_peer else None,
        ),
        'network': lambda: _run_network(log, quick, args.cache_dir),
        'live': lambda: _run_live(out_dir, log),
        'soak': lambda: soak.run_soak(
            log, episodes=soak.QUICK_EPISODES if quick else soak.EPISODES
        ),
        'stream': lambda: stream.run_stream(log, quick, args.cache_dir),
        'shards': lambda: shards.run_shards(log, quick, args.cache_dir),
    }
    log(f'parts: {", ".join(parts)}; methods: {", ".join(methods)}')
    failed = []
    for part in parts:
        t0 = time.monotonic()
        try:
            data = runners[part]()
        except Exception as exc:  # one broken part must not cost the others' results
            log(f'{part}: failed: {traceback.format_exc()}')
            data = {'status': f'failed: {type(exc).__name__}: {exc}'}
            failed.append(part)
        data['wall_s'] = time.monotonic() - t0
        data['date'] = _now()
        data['quick'] = quick
        save(part, data)
    results = {p: load(p) for p in PARTS}
    results['grid_reference'] = load('grid_reference')  # the grid's reference run
    targets = evaluate_targets(results)
    meta = {
        'out': args.output,
        'quick': quick,
        'only': args.only or [],
        'seconds': time.monotonic() - t_start,
        'date': _now(),
        'parts': parts,
        'python': sys.version.split()[0],
    }
    save('summary', {'meta': meta, 'targets': targets})
    plot_all(out_dir, results['grid'], results['cost'])
    soak.plot(out_dir, results['soak'])
    plot_stream(out_dir, results['stream'])
    write_readme(out_dir, results, targets, meta)
    for t in targets:
        log(f'target: {t["target"]}: {t["met"]} ({t["value"]})')
    log(f'done in {meta["seconds"] / 60:.1f} min; wrote {out_dir}')
    if failed:
        log(f'failed parts: {", ".join(failed)}')
    logf.close()
    return 1 if failed else 0
