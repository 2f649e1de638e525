"""``mlkm paper`` and ``mlkm bench``: the experiments' subcommands of the ``mlkm`` command.

The product's ``mlkm`` (mlkm_assoc.cli) names no experiment: it finds these two through the
``mlkm.commands`` entry points that this package's setup.cfg registers. Each is a function
taking the arguments after ``mlkm <name>`` and returning the exit status; the first line of
its docstring is its line in ``mlkm --help``. Imports are deferred so that ``mlkm --help``
loads nothing heavy.
"""

from __future__ import annotations

import argparse


def paper(argv: list[str]) -> int:
    """reproduce the paper's experiments"""
    args = paper_parser().parse_args(argv)
    from mlkm_experiments import paper as experiments

    return experiments.main_args(
        args.datasets, args.output, args.jobs, args.dnn_datasets, args.segment_size
    )


def bench(argv: list[str]) -> int:
    """benchmarks into results/bench (mlkm bench --help)"""
    from mlkm_experiments.bench import main

    return int(main(argv) or 0)


def paper_parser() -> argparse.ArgumentParser:
    from mlkm_core.associators import AssociatorConfig
    from mlkm_core.cli_args import positive_int, renamed_option

    default_k = AssociatorConfig.segment_size
    p = argparse.ArgumentParser(prog='mlkm paper', description=paper.__doc__)
    p.add_argument(
        '--datasets',
        type=positive_int,
        default=100,
        help='seeded datasets per configuration (default: 100)',
    )
    p.add_argument(
        '--dnn-datasets',
        type=positive_int,
        default=None,
        help='datasets per DNN split (default: min(datasets, 10))',
    )
    renamed_option(
        p, '--output', '--out', default='results/paper', help='output directory (results/paper)'
    )
    p.add_argument('--jobs', type=positive_int, default=2, help='worker processes (default: 2)')
    p.add_argument(
        '--segment-size',
        type=positive_int,
        default=default_k,
        help=f'MLKM segment size K (default: {default_k})',
    )
    return p
