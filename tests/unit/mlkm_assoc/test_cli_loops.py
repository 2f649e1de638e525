"""``mlkm loops``: virtual loops on the shipped NGSIM trajectories, for ``mlkm associate``."""

import re
from pathlib import Path

import numpy as np
import pytest

from mlkm_assoc import cli, cli_loops
from mlkm_core.csvio import read_detections
from mlkm_core.layout_file import read_layout_file
from mlkm_core.loops import even_positions, virtual_loops
from mlkm_core.trajectories import read_trajectories

NGSIM = Path(__file__).resolve().parents[3] / 'data' / 'ngsim_i80' / 'i80_trajectories_a.csv.gz'
FIVE = ['--stations', '5', '--start', '50', '--end', '450']


def _loops(tmp_path, *flags):
    out, lay = tmp_path / 'loops.csv', tmp_path / 'loops.yaml'
    argv = ['--input', str(NGSIM), *flags, '--output', str(out), '--layout', str(lay)]
    return cli_loops.main(argv), out, lay


def test_five_closed_stations_on_ngsim_give_400_detections_of_80_vehicles(tmp_path, capsys):
    rc, out, lay = _loops(tmp_path, *FIVE, '--closed')
    assert rc == 0
    printed = capsys.readouterr().out
    assert '400 detections of 80 vehicles (111 seen; closed road) at 5 stations' in printed
    data = read_detections(out)
    d = data.detections
    assert len(d) == 400 and np.unique(d.target).size == 80
    assert np.bincount(d.sensor_index).tolist() == [80] * 5  # every vehicle at every station
    assert data.layout.positions.tolist() == [50.0, 150.0, 250.0, 350.0, 450.0]
    # the file holds what the Python API gives, to the written decimals
    mem = virtual_loops(read_trajectories(NGSIM), even_positions(5, 50, 450), closed=True)
    m = mem.dataset.detections
    order = np.lexsort((d.target, d.sensor_index))
    mine = np.lexsort((m.target, m.sensor_index))
    assert d.target[order].tolist() == m.target[mine].tolist()
    assert d.stamp[order].tolist() == m.stamp[mine].tolist()
    assert d.velocity[order].tolist() == m.velocity[mine].tolist()
    assert d.lane[order].tolist() == m.lane[mine].tolist()
    assert d.length[order].tolist() == m.length[mine].tolist()
    road = read_layout_file(lay)
    assert road.layout.positions.tolist() == [50.0, 150.0, 250.0, 350.0, 450.0]
    assert road.layout.sensor_ids.tolist() == data.layout.sensor_ids.tolist()
    assert road.lanes.tolist() == [3] * 5 and road.layout.road_length == 507.2
    head = lay.read_text().splitlines()[:2]
    assert 'closed road' in head[0] and str(NGSIM) in head[0]
    assert head[1].startswith('# written by: mlkm loops --input') and '--closed' in head[1]


def test_the_output_is_associated_by_mlkm_associate_without_targets(tmp_path, capsys):
    rc, out, _ = _loops(tmp_path, *FIVE, '--closed')
    assert rc == 0
    tracks = tmp_path / 'tracks.csv'
    argv = ['associate', '--input', str(out), '--output', str(tracks), '--method', 'assignment']
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert '400 detections from 5 sensors' in printed and '80 targets' in printed
    assert 'accuracy:' in printed and tracks.is_file()


def test_open_road_default_stations_and_lanes_option(tmp_path, capsys):
    rc, out, lay = _loops(tmp_path, '--lanes', '6')
    assert rc == 0
    assert 'open road' in capsys.readouterr().out
    data = read_detections(out)
    # 10 stations over the covered span (10.78 .. 507.2 m, 5 % trimmed at each end)
    assert data.layout.n_sensors == 10
    assert data.layout.positions[0] == pytest.approx(35.601) and data.layout.positions[-1] == (
        pytest.approx(482.379)
    )
    assert np.unique(data.detections.target).size == 111
    # NGSIM lanes 1-3 of a 6-lane road: 5, 4, 3 from the right
    assert sorted(np.unique(data.detections.lane).tolist()) == [3, 4, 5]
    assert read_layout_file(lay).lanes.tolist() == [6] * 10


def test_explicit_positions_in_any_order(tmp_path, capsys):
    rc, out, _ = _loops(tmp_path, '--stations-at', '300,100.0004,200')
    assert rc == 0
    # rounded to 1 mm (the CSV's precision), sorted
    assert read_detections(out).layout.positions.tolist() == [100.0, 200.0, 300.0]


def test_via_the_mlkm_command(tmp_path, capsys):
    out = tmp_path / 'x.csv'
    argv = ['loops', '--input', str(NGSIM), '--stations-at', '100,200', '--output', str(out)]
    assert cli.main(argv) == 0
    assert out.is_file() and not list(tmp_path.glob('*.yaml'))


def test_the_old_spellings_still_work_with_a_note(tmp_path, capsys):
    rc, out, lay = _loops(tmp_path, '--at', '100,200')
    assert rc == 0 and lay.is_file()
    assert capsys.readouterr().err == 'mlkm loops: note: --at is deprecated; use --stations-at\n'
    argv = ['--input', str(NGSIM), '--stations', '2', '--output', str(tmp_path / 'b.csv')]
    assert cli_loops.main([*argv, '--layout-out', str(tmp_path / 'b.yaml')]) == 0
    err = capsys.readouterr().err
    assert err == 'mlkm loops: note: --layout-out is deprecated; use --layout\n'
    assert read_layout_file(tmp_path / 'b.yaml').layout.n_sensors == 2


@pytest.mark.parametrize(
    ('flags', 'message'),
    [
        (['--stations', '0'], 'argument --stations: must be >= 1'),
        (['--stations', '3', '--stations-at', '1,2'], 'not allowed with argument'),
        (['--stations-at', '100,200', '--start', '50'], '--start and --end place --stations'),
        (['--stations-at', '100,x'], "not a number: 'x'"),
        (['--stations-at', '100,100.0001'], 'two stations at one position'),
        (['--stations-at', '5,100'], r'station\(s\) at 5 m off the road the trajectories cover'),
        (
            ['--stations', '3', '--start', '50', '--end', '5000'],
            r'at 2525, 5000 m off the road the trajectories cover \(10.78 .. 507.2 m\)',
        ),
        (['--stations', '3', '--start', '400', '--end', '100'], '--start/--end: need end'),
        (['--lanes', '2'], 'lane id 3 on a 2-lane road'),
        (['--lanes', '0'], 'argument --lanes: must be >= 1'),
        (['--fcd-position', 'y'], 'invalid choice'),
        # no vehicle of the extract is observed from 11 m to 507 m
        (['--stations-at', '11,507', '--closed'], 'no vehicle is detected at every station'),
    ],
)
def test_bad_flags_exit_2_with_one_line_and_write_nothing(tmp_path, capsys, flags, message):
    rc, out, lay = _loops(tmp_path, *flags)
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith('mlkm loops: error: ') and err.count('\n') == 1, err
    assert re.search(message, err), err
    assert list(tmp_path.iterdir()) == []


def test_bad_inputs_and_outputs_exit_2_and_write_nothing(tmp_path, capsys):
    bad = tmp_path / 'in' / 'bad.csv'
    bad.parent.mkdir()
    bad.write_text('vehicle_id,time_s,y_m,speed_mps,lane_id,length_m\n1,0,abc,1,1,4\n')
    out = tmp_path / 'out'
    cases = [
        (['--input', str(bad)], 'bad.csv, line 2: not 6 numbers'),
        (['--input', str(tmp_path / 'none.csv')], 'none.csv: No such file'),
        (['--input', str(NGSIM), '--output', str(tmp_path)], '--output is a directory'),
        (
            ['--input', str(NGSIM), '--layout', str(out / 'same.csv')],
            '--output and --layout name the same file',
        ),
        (['--input', str(NGSIM), '--layout', str(tmp_path)], '--layout is a directory'),
        (['--input', str(NGSIM), '--output', str(NGSIM)], '--output is the input file'),
    ]
    for flags, message in cases:
        argv = ['--output', str(out / 'same.csv'), *flags]
        assert cli_loops.main(argv) == 2, flags
        err = capsys.readouterr().err
        assert err.startswith('mlkm loops: error: ') and err.count('\n') == 1, err
        assert message in err, err
        assert not out.exists()
    assert cli_loops.main(['--output', str(out / 'x.csv')]) == 2
    assert 'required: --input' in capsys.readouterr().err


def test_a_station_nobody_crosses_is_a_warning(tmp_path, capsys):
    # 10.78 m is the first frame of the extract: no frame lies before it
    rc, out, lay = _loops(tmp_path, '--stations-at', '10.78,100')
    assert rc == 0
    err = capsys.readouterr().err
    assert 'warning: no vehicle crosses the station(s) at 10.78 m' in err
    assert read_detections(out).layout.positions.tolist() == [100.0]
    assert read_layout_file(lay).layout.positions.tolist() == [10.78, 100.0]


FCD = """<fcd-export>
  <timestep time="0.00"><vehicle id="a" x="0.0" speed="10.0" lane="m0_1" distance="50.0"/>
  </timestep>
  <timestep time="1.00"><vehicle id="a" x="10.0" speed="10.0" lane="m0_1" distance="60.0"/>
    <vehicle id="b" x="0.0" speed="20.0" lane="m0_0" distance="50.0"/></timestep>
  <timestep time="2.00"><vehicle id="b" x="20.0" speed="20.0" lane="m0_0" distance="70.0"/>
  </timestep>
</fcd-export>
"""


def test_sumo_fcd_input_by_x_and_by_distance(tmp_path, capsys):
    fcd = tmp_path / 'fcd.xml'
    fcd.write_text(FCD)
    for flags, at in (([], '5'), (['--fcd-position', 'distance'], '55')):
        out = tmp_path / 'fcd.csv'
        argv = ['--input', str(fcd), '--stations-at', at, '--output', str(out), *flags]
        assert cli_loops.main(argv) == 0
        d = read_detections(out).detections
        # a (id 0) crosses halfway through 0..1 s in lane 1; b (id 1) at 1.25 s in lane 0
        assert d.target.tolist() == [0, 1] and d.stamp.tolist() == [0.5, 1.25]
        assert d.lane.tolist() == [1, 0] and np.isnan(d.length).all()
    capsys.readouterr()
