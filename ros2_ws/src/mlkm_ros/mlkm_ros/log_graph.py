"""The live graph on a detector log, beside ``mlkm associate`` on the same file: what
``make demo-real`` (real NGSIM traffic on one road) and ``make demo-network`` (a SUMO road
network) run.

:func:`offline` associates the log with the installed ``mlkm`` command line;
:func:`run_log_graph` starts, as separate processes on loopback DDS in a ROS domain of its
own: association_node, scorer_node, bag_recorder and log_source (mode episodes: the whole log
is one episode, real_time_factor 0), waits for the score, stops the recorder cleanly and the
rest, and returns the live score.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from mlkm_ros.domains import domain
from mlkm_ros.processes import (
    Graph,
    ScoreCollector,
    executable,
    recorder_args,
    start_association,
)

ACCURACY = re.compile(r'accuracy: ([\d.]+) % \((\d+)/(\d+)\)')


@dataclass(frozen=True)
class LiveRun:
    """The live graph's scores of the log (AssociationScore by episode id; the log is
    episode 0) and every process's exit code."""

    scores: dict
    codes: dict[str, int]

    @property
    def score(self):
        """The log's AssociationScore."""
        return self.scores[min(self.scores)]


def mlkm(*args: str) -> subprocess.CompletedProcess:
    """Run the installed ``mlkm`` command line; RuntimeError with its message on failure."""
    run = subprocess.run(
        [str(executable('mlkm_assoc', 'mlkm')), *args], capture_output=True, text=True
    )
    if run.returncode != 0:
        raise RuntimeError(f'mlkm {args[0]} failed ({run.returncode}): {run.stderr.strip()}')
    return run


def offline(log: Path, method: str, out: Path, *more: str) -> tuple[float, int, int]:
    """(accuracy, correct, total) of ``mlkm associate`` on ``log`` with ``method`` (``more``:
    further arguments, ``--layout`` for a road network)."""
    run = mlkm('associate', '--input', str(log), '--output', str(out), '--method', method, *more)
    m = ACCURACY.search(run.stdout)
    if m is None:
        raise RuntimeError(f'mlkm associate printed no accuracy:\n{run.stdout}')
    return float(m.group(1)) / 100.0, int(m.group(2)), int(m.group(3))


def run_dirs(label: str, given: Path | None, bags: Path) -> tuple[Path, Path] | None:
    """(the bag to write, the directory of its log, layout file and node logs) of a demo run:
    ``given`` or ``bags/<label>_<UTC time>``, the logs in ``<bag>/../logs/<bag name>``; None
    (said why) when the bag exists already."""
    stamp = time.strftime(f'{label.replace("-", "_")}_%Y%m%d_%H%M%S', time.gmtime())
    bag_dir = (given or bags / stamp).resolve()
    if bag_dir.exists():
        print(f'{label}: {bag_dir} exists already; choose another --bag-dir', file=sys.stderr)
        return None
    log_dir = bag_dir.parent / 'logs' / bag_dir.name
    log_dir.mkdir(parents=True, exist_ok=True)
    return bag_dir, log_dir


def run_log_graph(
    label: str, log: Path, layout: Path, method: str, bag_dir: Path, log_dir: Path, timeout: float
) -> LiveRun | None:
    """The live graph on ``log`` and its ``layout`` file (module docstring); None when a part
    failed (every process stopped, why and the tails of their output printed)."""
    with domain() as domain_id:
        print(f'{label}: ROS_DOMAIN_ID={domain_id}, loopback DDS; logs in {log_dir}')
        collector = ScoreCollector(domain_id)
        graph = Graph(domain_id, log_dir)
        try:
            start_association(
                graph,
                collector,
                method,
                ('bag_recorder', 'rosbag_mcap', 'bag_recorder', *recorder_args(bag_dir)),
            )
            source = graph.start(
                'log_source',
                'road_sensors',
                'log_source',
                '--ros-args',
                *('-p', f'log:={log}', '-p', f'layout:={layout}', '-p', 'mode:=episodes'),
                *('-p', 'real_time_factor:=0.0'),
                *('-p', 'wait_for_subscribers:=2'),  # association node + recorder
                *('-p', 'wait_for_truth_subscribers:=2'),  # scorer + recorder
            )
            why = collector.spin_until(
                lambda: len(collector.scores) >= 1, timeout=timeout, abort=graph.failed
            )
            if why:
                raise RuntimeError(f'the log was not scored: {why}')
            if source.wait(30.0) != 0:
                raise RuntimeError(graph.failed() or 'log_source did not finish')
            # The recorder may still be working off its backlog: wait until it is idle, then
            # stop it with SIGINT so that it closes the bag cleanly.
            collector.spin_until(lambda: False, timeout=0.3)
            graph.close_recorder(label)
        except (RuntimeError, KeyboardInterrupt) as exc:
            collector.close()
            graph.report_failure(label, exc)
            return None
        codes = graph.stop_all()
        collector.close()
    return LiveRun(dict(collector.scores), codes)
