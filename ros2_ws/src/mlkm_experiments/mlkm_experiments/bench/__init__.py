"""``mlkm bench``: accuracy grid, cost growth, Stone Soup side by side, SUMO traffic, live
throughput and a soak of the live graph.

Writes ``<out>/<part>.json`` for each part run (``grid``, ``peer``, ``cost``, ``sumo``,
``live``, ``soak``), ``summary.json`` (the targets: met or not, with the values), PNG plots and
``README.md`` (from every part's JSON present, so one part can be rerun alone with ``--only``).
Never part of ``make test``; ``--quick`` runs a small version (a smoke check). Paths come from
the arguments (``--output``, default ``results/bench`` under the current directory).

Modules: ``grid`` (every method on simulated cells, paper and clutter mode, time budgets),
``cost`` (runtime and memory growth), ``peer`` (Stone Soup), ``sumo`` (SUMO scenarios, with
and without lane and length), ``live`` (association node vs a bare subscriber), ``soak``
(memory of the live graph over many episodes), ``targets``, ``plots``, ``report``, ``main``.
"""

from .main import main

__all__ = ['main']
