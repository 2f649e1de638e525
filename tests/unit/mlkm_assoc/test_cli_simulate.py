"""``mlkm simulate``: the simulator's detections as the CSV that ``mlkm associate`` reads."""

import re

import numpy as np
import pytest

from mlkm_assoc import cli
from mlkm_core.csvio import read_detections
from mlkm_core.layout_file import read_layout_file
from mlkm_core.simulator import SimConfig, simulate_episodes, stream_origin
from mlkm_core.simulator_stream import simulate_stream

#: A seeded closed road with clutter: 2 episodes of 50 vehicles, 20 stations.
SEEDED = ['--seed', '3', '--episodes', '2', '--miss-rate', '0.05']
SEEDED += ['--false-alarms-per-vehicle', '0.02']


def _simulate(tmp_path, *flags):
    out, lay = tmp_path / 'sim.csv', tmp_path / 'sim.yaml'
    rc = cli.main(['simulate', *flags, '--output', str(out), '--layout', str(lay)])
    return rc, out, lay


def test_round_trip_simulate_then_associate_is_exact_on_a_seeded_case(tmp_path, capsys):
    rc, out, lay = _simulate(tmp_path, *SEEDED)
    assert rc == 0
    printed = capsys.readouterr().out
    assert re.search(r'^\d+ detections \(\d+ false alarms\) of 2 episodes of 50 vehicles', printed)
    data = read_detections(out)
    d = data.detections
    # the file holds the core's episodes, stamps moved to t >= 0, vehicles numbered per episode
    config = SimConfig(miss_probability=0.05, false_alarm_rate=0.02)
    eps = simulate_episodes(config, 3, 2)
    origin = stream_origin(eps)
    truth = [e.detections.target + 50 * k * (e.detections.target >= 0) for k, e in enumerate(eps)]
    assert len(d) == sum(len(e.detections) for e in eps)
    assert sorted(d.target.tolist()) == sorted(np.concatenate(truth).tolist())
    assert np.unique(d.target[d.target >= 0]).size == 100  # no id shared by two episodes
    stamps = np.concatenate([e.detections.stamp for e in eps]) + origin
    assert np.sort(d.stamp).tolist() == np.sort(np.round(stamps, 3)).tolist()
    assert d.stamp.min() >= 0
    assert data.header[-3:] == ['target_id', 'lane', 'length_m']
    road = read_layout_file(lay)
    assert road.layout.positions.tolist() == data.layout.positions.tolist()
    assert road.layout.sensor_ids.tolist() == data.layout.sensor_ids.tolist()
    assert lay.read_text().splitlines()[1].startswith('# written by: mlkm simulate --seed 3')
    tracks = tmp_path / 'tracks.csv'
    argv = ['associate', '--input', str(out), '--output', str(tracks), '--method', 'multiframe']
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    n_true = int(np.sum(d.target >= 0))
    m = re.search(r'accuracy: ([\d.]+) % \((\d+)/(\d+)\)', printed)
    assert int(m.group(3)) == n_true
    assert float(m.group(1)) >= 99.0  # multiframe on this seeded case: 1888/1888


def test_open_road_for_a_duration_is_the_stream_simulator(tmp_path, capsys):
    rc, out, lay = _simulate(tmp_path, '--duration', '300', '--stations', '6', '--seed', '1')
    assert rc == 0
    assert 'vehicles in 300 s (open road)' in capsys.readouterr().out
    d = read_detections(out).detections
    core = list(simulate_stream(SimConfig(n_sensors=6), 1, duration=300.0))
    assert len(d) == len(core) > 0
    assert np.sort(d.stamp).tolist() == sorted(round(c.stamp, 3) for c in core)
    assert d.stamp.max() <= 300.0
    assert read_layout_file(lay).layout.n_sensors == 6


def test_the_old_spelling_of_output_still_works_with_a_note(tmp_path, capsys):
    out = tmp_path / 'old.csv'
    assert cli.main(['simulate', '--out', str(out), '--vehicles', '5', '--stations', '3']) == 0
    err = capsys.readouterr().err
    assert err == 'mlkm simulate: note: --out is deprecated; use --output\n'
    assert len(read_detections(out).detections) == 15


@pytest.mark.parametrize(
    ('flags', 'message'),
    [
        (['--miss-rate', '1.5'], "argument --miss-rate: must be in [0, 1), got '1.5'"),
        (['--episodes', '0'], 'argument --episodes: must be >= 1, got 0'),
        (['--episodes', '2', '--duration', '60'], 'not allowed with argument --episodes'),
        (['--arrival-rate', '0.5'], '--arrival-rate needs --duration (an open road)'),
        (['--seed', '-1'], 'argument --seed: must be in [0, 2^32 - 1]'),
        (['--stamp-jitter', 'nan'], "argument --stamp-jitter: must be finite, got 'nan'"),
    ],
)
def test_bad_flags_exit_2_with_one_line_and_write_nothing(tmp_path, capsys, flags, message):
    rc, out, lay = _simulate(tmp_path, *flags)
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith('mlkm simulate: error: ') and message in err
    assert err.count('\n') == 1
    assert not out.exists() and not lay.exists()


def test_missing_output_and_a_directory_as_output_are_refused(tmp_path, capsys):
    assert cli.main(['simulate']) == 2
    assert capsys.readouterr().err == (
        'mlkm simulate: error: one of the arguments --output is required\n'
    )
    assert cli.main(['simulate', '--output', str(tmp_path)]) == 2
    assert 'is a directory' in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
