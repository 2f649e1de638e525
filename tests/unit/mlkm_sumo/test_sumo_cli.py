"""``mlkm sumo`` (mlkm_sumo.cli.main): writes a detections CSV that ``mlkm associate`` reads;
bad input exits 2 with one clear line and writes nothing. Also the passage stream."""

import json

import numpy as np
import pytest

from mlkm_sumo import MeasurementConfig, PassageStream
from mlkm_sumo.cli import main
from mlkm_sumo.measurement import FALSE_ALARM

read_detections = pytest.importorskip('mlkm_assoc.cli').read_detections
associate = pytest.importorskip('mlkm_assoc.cli').main
read_network_file = pytest.importorskip('mlkm_core.network_file').read_network_file


@pytest.fixture
def cache(tmp_path_factory):
    return str(tmp_path_factory.getbasetemp() / 'sumo_cli_cache')


def test_cli_writes_a_csv_that_reads_back(tmp_path, cache, capsys):
    out, road = tmp_path / 'data.csv', tmp_path / 'road.json'
    argv = ['--scenario', 'highway', '--vehicles', '40', '--stations', '6', '--seed', '1',
            '--output', str(out), '--cache-dir', cache, '--road', str(road)]  # fmt: skip
    assert main(argv) == 0
    assert f'-> {out}' in capsys.readouterr().out
    layout, dets, rows, header = read_detections(out)
    assert header == [
        'sensor_id',
        'position_m',
        'stamp_s',
        'velocity_mps',
        'target_id',
        'lane',
        'length_m',
    ]
    assert layout.n_sensors == 6 and dets.target is not None
    first = dets.target >= 0
    assert np.unique(dets.target[first]).size == 40
    assert np.all(np.bincount(dets.sensor_index[first]) == 40)  # every vehicle, every station
    lanes = np.array([int(r['lane']) for r in rows])
    assert set(lanes) <= {0, 1, 2}
    info = json.loads(road.read_text())
    assert [s['lanes'] for s in info['stations']] == [3] * 6
    assert [s['position_m'] for s in info['stations']] == pytest.approx(layout.positions)
    # same seed, same data; the old spelling of --output still works, with a note
    out2 = tmp_path / 'again.csv'
    assert main([*argv[:-6], '--out', str(out2), '--cache-dir', cache]) == 0
    assert out2.read_text() == out.read_text()
    note = 'mlkm sumo: note: --out is deprecated; use --output\n'
    assert capsys.readouterr().err.startswith(note)


def test_cli_duration_and_given_stations(tmp_path, cache):
    out = tmp_path / 'd.csv'
    argv = ['--scenario', 'ramps', '--duration', '120', '--stations-at', '300,900,1800',
            '--output', str(out), '--cache-dir', cache, '--false-alarm-rate', '600']  # fmt: skip
    assert main(argv) == 0
    layout, dets, rows, _ = read_detections(out)
    assert layout.positions.tolist() == [300.0, 900.0, 1800.0]
    assert dets.stamp.max() <= 120.0
    assert np.any(dets.target == FALSE_ALARM)
    assert all(float(r['length_m']) > 0 for r in rows)


def test_cli_writes_a_network_that_mlkm_associate_reads(tmp_path, cache, capsys):
    """--network: the detections CSV and the network layout file of a drawn interchange,
    associated across its junctions by ``mlkm associate --layout``."""
    out, layout = tmp_path / 'net.csv', tmp_path / 'net.yaml'
    argv = ['--network', 'interchange', '--vehicles', '40', '--seed', '2', '--output', str(out),
            '--layout', str(layout), '--cache-dir', cache]  # fmt: skip
    assert main(argv) == 0
    assert f'-> {out}, layout -> {layout}' in capsys.readouterr().out
    net = read_network_file(layout)
    rows = out.read_text().splitlines()
    assert rows[0] == 'sensor_id,position_m,stamp_s,velocity_mps,target_id,lane,length_m'
    ids = {int(r.split(',')[0]) for r in rows[1:]}
    assert ids <= {int(i) for i in net.station_ids} and len(net.links) > 1
    assert {int(r.split(',')[4]) for r in rows[1:]} >= set(range(40))
    assert associate(['associate', '--input', str(out), '--layout', str(layout), '--output',
                      str(tmp_path / 'tracks.csv'), '--method', 'assignment']) == 0  # fmt: skip
    shown = capsys.readouterr().out
    assert f'road network of {len(net.links)} links' in shown
    accuracy = float(shown.split('accuracy: ')[1].split(' %')[0])
    assert accuracy > 80.0


@pytest.mark.parametrize(
    ('argv', 'message'),
    [
        (['--network', 'interchange'], '--network needs --layout'),
        (['--network', 'grid', '--layout', 'x.yaml', '--duration', '60'], 'do not apply'),
        (['--network', 'interchange', '--layout', 'x.yaml', '--flow', '900'], 'cannot override'),
        (['--scenario', 'highway', '--layout', 'x.yaml'], '--layout goes with --network'),
        (['--scenario', 'autobahn'], "unknown scenario 'autobahn'"),
        (['--scenario', 'highway', '--stations-at', '1000,x'], 'positions in metres'),
        (['--scenario', 'ramps', '--stations-at', '1000,1500'], 'lies in a junction'),
        (['--scenario', 'highway', '--stations-at', '900,800'], 'strictly increasing'),
        (['--scenario', 'highway', '--miss-rate', '2'], 'miss_rate'),
        (['--scenario', 'highway', '--vehicles', '0'], 'n_vehicles must be >= 1'),
    ],
)
def test_cli_bad_input_exits_2_with_a_message(argv, message, tmp_path, cache, capsys):
    out = tmp_path / 'never.csv'
    extra = [] if '--vehicles' in argv else ['--vehicles', '5']
    assert main([*argv, *extra, '--output', str(out), '--cache-dir', cache]) == 2
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]  # argparse problems come after the usage line
    assert last.startswith('mlkm sumo: error: ') and message in last
    assert 'Traceback' not in err
    assert not out.exists()


def test_stream_yields_measured_passages_in_time_order(cache):
    cfg = MeasurementConfig(stamp_jitter=0.05, false_alarm_rate=200.0)
    stream = PassageStream('highway', n_stations=5, seed=4, duration=150.0, measurement=cfg,
                           cache_dir=cache)  # fmt: skip
    assert stream.road.n_stations == 5  # known before SUMO starts
    passages = list(stream)
    times = np.array([p.time for p in passages])
    assert len(passages) > 100 and np.all(np.diff(times) >= 0)
    real = [p for p in passages if p.vehicle]
    assert any(not p.vehicle for p in passages)  # false alarms
    for p in real:
        assert 0 <= p.lane < stream.road.lanes[p.station]
        assert p.position == stream.road.layout.positions[p.station]
    # a vehicle is reported at increasing times along the road
    by_vehicle = {}
    for p in real:
        by_vehicle.setdefault(p.vehicle, []).append(p.station)
    assert all(s == sorted(s) for s in by_vehicle.values())
