"""Running the association node in stream mode against a source, as the stream bench parts
and the paced shards part do: the graph in a domain of its own, the node's /diagnostics
sampled as it goes, optionally the resident set of the node and of its tracker process.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

from .soak import vm_rss

#: stations of every stream run [-]
SENSORS = 20
SAMPLE_PERIOD = 1.0  # [s] RSS samples
NODE = '/association_node'
PUBLISHED = re.compile(r'published (\d+) detections')
#: what an RSS sample takes from the node's latest /diagnostics sample (``_sample``)
RSS_FIELDS = ('received', 'pushed', 'working_set', 'committed')


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
                    last = samples[-1] if samples else {}
                    rss_samples.append(
                        {
                            't': now - t0,
                            **{k: last.get(k) for k in RSS_FIELDS},
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
        'working_set': int(values.get('stream.working_set') or 0),
        'committed': _num(values, 'stream.committed_until'),
    }


def _num(values: dict, key: str) -> float | None:
    v = values.get(key)
    return None if v in (None, '') else float(v)
