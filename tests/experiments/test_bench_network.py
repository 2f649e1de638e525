"""``mlkm bench --only network``: one seed per family through the CLI, its JSON, report and
targets, and the targets on hand-made results."""

from __future__ import annotations

import json

import pytest

from mlkm_experiments.bench import network


@pytest.mark.slow
# every network method and the stream on three SUMO networks: 1-3 min on a 2-core machine
# that two other processes keep busy (the stream solves its windows inside its pushes)
@pytest.mark.timeout(900)
def test_one_seed_per_family_end_to_end_through_the_cli(tmp_path):
    from mlkm_assoc import cli

    out = tmp_path / 'out'
    argv = ['bench', '--quick', '--only', 'network', '--output', str(out)]
    assert cli.main([*argv, '--cache-dir', str(tmp_path / 'cache')]) == 0
    data = json.loads((out / 'network.json').read_text())
    assert [c['family'] for c in data['cells']] == list(network.FAMILIES)
    assert 'long' not in data  # the hour-long inputs run in full runs only
    for cell in data['cells']:
        assert cell['seeds'] == [1] and cell['draws'][0]['family'] == cell['family']
        assert cell['overrides'] == network.QUICK_OVERRIDES
        assert cell['draws'][0]['vehicles'] == network.QUICK_OVERRIDES['vehicles']
        for variant in network.VARIANTS:
            runs = cell['variants'][variant]
            assert set(runs) == {'assignment', 'gmlkm', 'multiframe', 'mlkm_robust',
                                 'assignment_stream'}  # fmt: skip
            for rec in runs.values():
                (row,) = rec['runs']
                assert 0.0 < row['accuracy'] <= 1.0
                assert row['detections'] == cell['detections_mean']
    # the tracking method beats the G-MLKM baseline on the grid's seed 1 by far
    grid = data['cells'][2]['variants']['time_speed']
    assert (
        grid['assignment']['summary']['accuracy_mean']
        > grid['gmlkm']['summary']['accuracy_mean'] + 0.05
    )
    assert '## Road networks: SUMO network families' in (out / 'README.md').read_text()
    targets = json.loads((out / 'summary.json').read_text())['targets']
    assert 'network grid: the best method >= gmlkm + 5 points' in [t['target'] for t in targets]


def _cell(family: str, best: tuple[float, float], base: tuple[float, float]) -> dict:
    def rec(acc: float) -> dict:
        return {'summary': {'n': 3, 'accuracy_mean': acc, 'accuracy_min': acc,
                            'accuracy_max': acc}}  # fmt: skip

    return {
        'family': family,
        'variants': {
            v: {'assignment': rec(best[k]), 'gmlkm': rec(base[k]),
                'multiframe': rec(best[k] - 0.05), 'stonesoup': rec(0.1)}
            for k, v in enumerate(network.VARIANTS)
        },
    }  # fmt: skip


def test_the_targets_on_hand_made_results():
    data = {
        'cells': [
            _cell('interchange', (0.96, 0.995), (0.90, 0.90)),
            _cell('arterial', (0.95, 0.96), (0.92, 0.80)),
        ],
        'speed': {'seconds': 75.0, 'stations': 120},
        'stream_speed': {'latency_ms_p95': 30.0, 'latency_ms_max': 900.0},
    }
    got = {t['target']: t['met'] for t in network.network_targets(data)}
    assert got == {
        'network interchange: the best method (time, speed) >= 95%': True,
        'network interchange: the best method (+ lane, length) >= 99%': True,
        'network interchange: the best method >= gmlkm + 5 points': True,
        'network interchange: every tracking method >= gmlkm': True,  # Stone Soup is no method
        'network arterial: the best method (time, speed) >= 90%': True,
        'network arterial: the best method (+ lane, length) >= 97%': False,
        'network arterial: the best method >= gmlkm + 5 points': False,  # +3 in time, speed
        'network arterial: every tracking method >= gmlkm': False,  # multiframe 90 % < 92 %
        'network stream: p95 detection-to-track latency < 50 ms on 2000 vehicles '
        '(core, 20x real time)': True,
        'network speed: 2000 vehicles associate in < 60 s': False,
    }
    assert network.network_targets({})[0]['met'] is None


def test_the_bars_take_the_best_tracking_method_of_each_variant():
    cell = _cell('interchange', (0.96, 0.98), (0.90, 0.90))
    cell['variants']['lane_length']['multiframe']['summary']['accuracy_mean'] = 0.992
    cell['variants']['lane_length']['stonesoup']['summary']['accuracy_mean'] = 0.999  # a peer
    got = {t['target']: (t['met'], t['value']) for t in network.network_targets({'cells': [cell]})}
    assert got['network interchange: the best method (+ lane, length) >= 99%'] == (
        True,
        'multiframe 99.20%',
    )
    assert got['network interchange: the best method (time, speed) >= 95%'] == (
        True,
        'assignment 96.00%',
    )


def test_stone_soup_on_a_network_follows_two_vehicles_that_swap_at_a_diverge():
    pytest.importorskip('stonesoup')
    import numpy as np

    from mlkm_core.network import RoadLink, RoadNetwork
    from mlkm_core.types import Detections
    from mlkm_experiments.bench.peer_network import stonesoup_network_associate

    # link 0 splits into links 1 and 2; stations 2 and 3 stand at the same offset on them,
    # so only the hop's distance from the track's last station places a detection
    net = RoadNetwork(
        links=(RoadLink(0, 'in', 1000.0), RoadLink(1, 'left', 600.0), RoadLink(2, 'right', 600.0)),
        connections=((0, 1), (0, 2)),
        station_ids=np.arange(4),
        station_names=('a', 'b', 'c', 'd'),
        station_links=np.array([0, 0, 1, 2]),
        station_offsets=np.array([300.0, 800.0, 200.0, 200.0]),
    )
    # A (20 m/s) turns left; B (25 m/s) overtakes it on link 0 and turns right
    rows = [(0, 0.0, 20.0, 0), (1, 25.0, 20.0, 0), (2, 45.0, 20.0, 0),
            (0, 2.0, 25.0, 1), (1, 22.0, 25.0, 1), (3, 38.0, 25.0, 1)]  # fmt: skip
    s, t, v, k = (np.array(c) for c in zip(*rows, strict=True))
    d = Detections(s.astype(np.int64), t.astype(float), v.astype(float), k.astype(np.int64))
    labels = stonesoup_network_associate(net, d)
    assert labels[0] == labels[1] == labels[2] >= 0
    assert labels[3] == labels[4] == labels[5] >= 0 and labels[0] != labels[3]


def test_the_long_inputs_section_has_one_row_per_seed_and_method():
    from mlkm_experiments.bench.network_long import long_lines

    def row(acc: float) -> dict:
        return {'accuracy': acc}

    long = {
        'family': 'interchange',
        'duration': 3600.0,
        'methods': ['assignment', 'assignment_stream'],
        'runs': [
            {'seed': 1, 'detections': 12000, 'rows': {
                'time_speed': {'assignment': row(0.8585), 'assignment_stream': row(0.8351)},
                'lane_length': {'assignment': row(0.9546), 'assignment_stream': row(0.9146)},
            }},
        ],
    }  # fmt: skip
    lines = long_lines(long)
    assert lines[0] == '### Long inputs: an hour of interchange traffic'
    assert '| 1 | 12000 | `assignment` | 85.85 | 95.46 |' in lines
    assert '| 1 | 12000 | `assignment_stream` | 83.51 | 91.46 |' in lines
    assert long_lines({}) == []


@pytest.mark.slow
# five minutes of SUMO traffic and one batch run: seconds, more on a busy machine
@pytest.mark.timeout(300)
def test_continuous_traffic_on_an_interchange_comes_as_a_dataset_the_batch_links(tmp_path):
    from mlkm_core.metrics import accuracy
    from mlkm_core.network_assoc import associate_network
    from mlkm_experiments.bench.network_long import hour_dataset

    draw, net, d = hour_dataset('interchange', 1, 300.0, tmp_path)
    assert draw.family == 'interchange' and len(d) > 500
    assert d.stamp.max() < 300.0 and set(d.sensor_index.tolist()) <= set(range(net.n_stations))
    # no false alarms by default; a lane change's double report targets no vehicle
    assert d.target.min() >= -1 and (d.target >= 0).mean() > 0.99
    labels = associate_network(net, d, 'assignment')
    assert accuracy(labels, d.target).accuracy > 0.85  # 88.48 % (seeded SUMO)
