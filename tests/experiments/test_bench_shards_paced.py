"""The paced shards bench: its verdict and clocks on hand-made numbers, and one paced run of
two shards over loopback DDS on a short SUMO log."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from mlkm_core.shards.regions import split_road
from mlkm_experiments.bench import shards_paced as paced
from mlkm_sumo.api import generate

GOOD = {'latency_p95': 0.02, 'road_rate': 395.0, 'commit_lag_at_end': 40.0}


@pytest.mark.parametrize(
    'change,ok',
    [
        ({}, True),
        ({'latency_p95': 0.051}, False),  # over the 50 ms bound
        ({'latency_p95': None}, False),  # no latency measured
        ({'road_rate': 0.85 * 400.0}, False),  # the source was slowed down
        ({'commit_lag_at_end': paced.COMMIT_LAG_MAX + 1.0}, False),  # solves fell behind
    ],
)
def test_a_rate_is_sustained_only_when_every_node_keeps_every_bound(change, ok) -> None:
    nodes = {'/shard_0/association_node': GOOD, '/shard_1/association_node': {**GOOD, **change}}
    assert paced.sustained(nodes, 400.0) is ok


def test_the_commit_lag_bound_follows_the_nodes_lag() -> None:
    behind = {'/association_node': {**GOOD, 'commit_lag_at_end': 25.0}}
    assert paced.sustained(behind, 400.0)  # 25 s behind at a 30 s lag: kept up
    assert not paced.sustained(behind, 400.0, lag=3.0)  # at 3 s: fell behind (bound 24 s)
    assert paced.commit_lag_max(3.0) == 3.0 + 2 * paced.SOLVE_INTERVAL + paced.REORDER


def test_the_handoff_clock_times_each_offer_to_its_continuation(monkeypatch) -> None:
    from road_sensor_msgs.msg import Track, TrackHandoff

    now = iter([100.0, 101.0, 104.5, 106.0])
    monkeypatch.setattr(paced.time, 'time', lambda: next(now))

    def msg(stamp: float, offers=(), continued=()) -> TrackHandoff:
        m = TrackHandoff(offers=[Track(track_id=t) for t in offers])
        m.continued_ids = list(continued)
        m.continuing_ids = [7] * len(continued)
        m.header.stamp.sec, m.header.stamp.nanosec = int(stamp), round(stamp % 1 * 1e9)
        return m

    clock = paced.HandoffClock()
    clock(msg(99.99, offers=[11]))  # arrives at 100.0
    clock(msg(100.98, offers=[11, 12]))  # a later offer of 11 does not restart its clock
    clock(msg(104.4, continued=[11]))  # 11 taken at 104.5
    clock.source_ended = 105.0
    clock(msg(105.9, continued=[12]))  # at the flush, after the source: counted, not timed
    assert clock.delays == [4.5] and clock.continued == 2
    assert clock.transits == pytest.approx([0.01, 0.02, 0.1, 0.1])


def test_tree_cpu_counts_the_descendants() -> None:
    # a child that spends 0.3 s of CPU in a grandchild, then waits for its stdin to close
    code = (
        'import subprocess, sys; '
        "g = subprocess.Popen([sys.executable, '-c', "
        "'import time, sys\\nt = time.process_time()\\nwhile time.process_time() - t < 0.3: "
        "pass\\nprint(1, flush=True)\\nsys.stdin.read()'], stdin=subprocess.PIPE, "
        'stdout=subprocess.PIPE, text=True); '
        'g.stdout.readline(); print(1, flush=True); sys.stdin.read()'
    )
    child = subprocess.Popen(
        [sys.executable, '-c', code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout.readline().strip() == '1'
        assert paced.tree_cpu(child.pid) >= 0.3
        assert paced.tree_cpu(os.getpid()) >= paced.tree_cpu(child.pid)
    finally:
        child.stdin.close()
        child.wait(30)


def test_report_lines_name_the_highest_rate_and_its_figures() -> None:
    nodes = {'/association_node': {**GOOD, 'cores': 0.9}}
    run = {
        'rate': 200.0, 'nodes': nodes, 'handoff_delay': {'count': 0},
        'handoff_transit': {'count': 0},
    }  # fmt: skip
    two = {
        **run,
        'rate': 400.0,
        'nodes': {
            '/shard_0/association_node': {**GOOD, 'cores': 0.8},
            '/shard_1/a': {**GOOD, 'cores': 0.7},
        },  # fmt: skip
        'merge_cores': 0.1,
        'handoff_delay': {'count': 3, 'p50': 2.0, 'p95': 3.0},
        'handoff_transit': {'count': 9, 'p50': 0.001, 'p95': 0.004},
    }
    result = {
        'data': paced.DATA, 'detections': 1000, 'cpus': 2,
        'configs': [
            {'shards': 1, 'highest_rate': 200.0, 'vs_one': 1.0, 'runs': [run]},
            {'shards': 2, 'highest_rate': 400.0, 'vs_one': 2.0, 'runs': [two]},
        ],
    }  # fmt: skip
    lines = paced.report_lines(result)
    assert '| 1 | 200 | 1.00 | 0.90 | 20.0 | - | - |' in lines
    two_row = '| 2 | 400 | 2.00 | 0.80, 0.70 (merge 0.10) | 20.0, 20.0 | 2.0 / 3.0 | 1.0 / 4.0 |'
    assert two_row in lines


@pytest.mark.slow
@pytest.mark.ros
def test_two_shards_paced_over_dds_measure_and_hand_tracks_over(tmp_path, ros_domain_id) -> None:
    # 200 s of a highway (1869 detections, 19 s at 100 det/s) and a 10 s lag: the run ends
    # once the quiet road is flushed, 10 s of wall time after the source
    data = {'scenario': 'highway', 'stations': 20, 'duration': 200.0, 'seed': 3}
    files = paced.write_log(tmp_path, tmp_path / 'sumo_cache', data)
    r = paced.run_rate(ros_domain_id, tmp_path / 'run', files, 2, 100.0, lag=10.0)
    # the measurements are real ones (whether 100 det/s is sustained depends on the load)
    assert r['lag'] == 10.0 and r['sustained'] == paced.sustained(r['nodes'], 100.0, 10.0)
    assert sum(n['received'] for n in r['nodes'].values()) > files['detections']  # margins
    for n in r['nodes'].values():
        assert n['cores'] > 0 and 0 < n['latency_p50'] <= n['latency_p95']
        assert 0 < n['road_rate'] <= 1.5 * 100.0
    assert r['merge_cores'] > 0
    # the vehicles seen on both sides of the border are continued across it, each once
    d = generate(
        data['scenario'], n_stations=data['stations'], seed=data['seed'],
        duration=data['duration'], cache_dir=tmp_path / 'sumo_cache',
    ).detections  # fmt: skip
    first = split_road(data['stations'], 2)[1].own[0]
    crossing = set(d.target[d.sensor_index == first - 1]) & set(d.target[d.sensor_index == first])
    assert len(crossing) > 80
    assert 0.95 * len(crossing) <= r['continued'] <= len(crossing)
    assert 0 < r['handoff_delay']['p50'] <= r['handoff_delay']['p95']
    assert 0 < r['handoff_transit']['p50'] < 1.0
