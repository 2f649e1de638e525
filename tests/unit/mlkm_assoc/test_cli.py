"""The offline CLI: ``mlkm associate`` on good and malformed CSV files."""

import csv
import re

import numpy as np
import pytest

from mlkm_assoc import cli
from mlkm_assoc.cli import main, read_detections
from mlkm_core.simulator import SimConfig, simulate

HEADER = 'sensor_id,position_m,stamp_s,velocity_mps,target_id'


def _write(path, truth=True, seed=0):
    ds = simulate(SimConfig(n_targets=12, n_sensors=10), seed)
    d = ds.detections
    lines = [HEADER if truth else HEADER.rsplit(',', 1)[0]]
    for i in range(len(d)):
        k = d.sensor_index[i]
        row = (
            f'{100 + k},{float(ds.layout.positions[k])!r},{float(d.stamp[i])!r},'
            f'{float(d.velocity[i])!r}'
        )
        lines.append(row + (f',{d.target[i]}' if truth else ''))
    path.write_text('\n'.join(lines) + '\n')
    return ds


def test_good_csv_gets_track_ids_and_accuracy(tmp_path, capsys):
    ds = _write(tmp_path / 'in.csv')
    rc = main(
        [
            'associate',
            '--input',
            str(tmp_path / 'in.csv'),
            '--output',
            str(tmp_path / 'out.csv'),
            '--method',
            'mlkm',
            '--segment-size',
            '5',
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert 'accuracy:' in out and 'link precision' in out and 'identity switches' in out
    with open(tmp_path / 'out.csv') as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(ds.detections)
    assert list(rows[0]) == HEADER.split(',') + ['track_id']
    tracks = np.array([int(r['track_id']) for r in rows])
    assert tracks.min() >= 0 and np.unique(tracks).size <= 12
    # the printed accuracy is the accuracy of the written tracks
    from mlkm_core.metrics import accuracy

    acc = accuracy(tracks, np.array([int(r['target_id']) for r in rows]))
    assert f'{100 * acc.accuracy:.2f} %' in out


def test_csv_without_truth_prints_no_accuracy(tmp_path, capsys):
    _write(tmp_path / 'in.csv', truth=False)
    rc = main(
        [
            'associate',
            '--input',
            str(tmp_path / 'in.csv'),
            '--output',
            str(tmp_path / 'out.csv'),
            '--method',
            'kmeans_pp',
            '--targets',
            '12',
        ]
    )
    assert rc == 0
    assert 'accuracy' not in capsys.readouterr().out
    assert (tmp_path / 'out.csv').read_text().splitlines()[0].endswith('velocity_mps,track_id')


def test_reader_maps_sensor_ids_to_positions(tmp_path):
    ds = _write(tmp_path / 'in.csv')
    layout, dets, rows, header = read_detections(tmp_path / 'in.csv')
    assert np.allclose(layout.positions, ds.layout.positions)
    assert layout.sensor_ids.tolist() == list(range(100, 110))
    assert np.array_equal(dets.target, ds.detections.target)


@pytest.mark.parametrize(
    'line,edit,message',
    [
        (4, lambda r: r.replace(r.split(',')[2], 'abc', 1), 'line 4: stamp_s is not a number'),
        (7, lambda r: r + ',9', 'line 7: expected 5 fields, got 6'),
        (
            3,
            lambda r: ','.join([*r.split(',')[:3], '-3', r.split(',')[4]]),
            'line 3: velocity_mps must be > 0',
        ),
        (
            5,
            lambda r: ','.join([r.split(',')[0], '12345.5', *r.split(',')[2:]]),
            'line 5: sensor 100 at position_m 12345.5',
        ),
        (6, lambda r: ','.join([*r.split(',')[:4], 'x']), 'line 6: target_id is not an integer'),
        (
            1,
            lambda r: 'sensor,position_m,stamp_s,velocity_mps,target_id',
            'line 1: missing column(s) sensor_id',
        ),
        (
            1,
            lambda r: 'sensor_id,position_m,stamp_s,velocty_mps,target_id',
            "line 1: missing column(s) velocity_mps; unknown column 'velocty_mps' "
            '(did you mean velocity_mps?)',
        ),
        (
            2,
            lambda r: ','.join([r.split(',')[0], '-0.5', *r.split(',')[2:]]),
            'line 2: position_m must be >= 0 (on the road) and finite, got -0.5',
        ),
    ],
)
def test_malformed_csv_names_the_line_and_writes_nothing(tmp_path, capsys, line, edit, message):
    _write(tmp_path / 'in.csv')
    lines = (tmp_path / 'in.csv').read_text().splitlines()
    lines[line - 1] = edit(lines[line - 1])
    (tmp_path / 'bad.csv').write_text('\n'.join(lines) + '\n')
    rc = main(
        ['associate', '--input', str(tmp_path / 'bad.csv'), '--output', str(tmp_path / 'out.csv')]
    )
    assert rc == 2
    err = capsys.readouterr().err
    assert message in err and 'bad.csv' in err
    assert not (tmp_path / 'out.csv').exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bad.csv', 'in.csv']


def test_missing_file_and_unknown_method(tmp_path, capsys):
    assert (
        main(
            [
                'associate',
                '--input',
                str(tmp_path / 'none.csv'),
                '--output',
                str(tmp_path / 'o.csv'),
            ]
        )
        == 2
    )
    assert 'cannot read' in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(['associate', '--input', 'x', '--output', 'y', '--method', 'nope'])
    assert exc.value.code == 2


def _associate(tmp_path, name, *extra):
    return main(
        ['associate', '--input', str(tmp_path / name), '--output', str(tmp_path / 'out.csv')]
        + list(extra)
    )


def _lines(tmp_path, name='in.csv'):
    return (tmp_path / name).read_text().splitlines()


def _save(tmp_path, lines, name='bad.csv'):
    (tmp_path / name).write_text('\n'.join(lines) + '\n')


def _out_rows(tmp_path):
    with open(tmp_path / 'out.csv') as f:
        return list(csv.DictReader(f))


def _absurd_rows(lines):
    """Two extra rows with a velocity of 1e308 m/s and a stamp of 1e300 s, as lines 3 and 6."""
    fast = lines[1].split(',')
    fast[3] = '1e308'
    late = lines[2].split(',')
    late[2] = '1e300'
    return [lines[0], lines[1], ','.join(fast), *lines[2:4], ','.join(late), *lines[4:]]


def test_absurd_values_refuse_the_file_naming_every_line(tmp_path, capsys):
    _write(tmp_path / 'in.csv')
    _save(tmp_path, _absurd_rows(_lines(tmp_path)))
    assert _associate(tmp_path, 'bad.csv') == 2
    err = capsys.readouterr().err
    assert 'bad.csv: 2 invalid rows' in err
    assert 'line 3: velocity_mps 1e+308 is outside [0.01, 150] m/s' in err
    assert 'line 6: stamp_s 1e300 is outside [-1e+12, 1e+12] s' in err
    assert '--skip-invalid' in err
    assert not (tmp_path / 'out.csv').exists()


def test_skip_invalid_associates_the_rest_and_writes_the_rejected_rows(tmp_path, capsys):
    _write(tmp_path / 'in.csv')
    assert _associate(tmp_path, 'in.csv') == 0
    clean_out = capsys.readouterr().out
    clean = [r['track_id'] for r in _out_rows(tmp_path)]
    _save(tmp_path, _absurd_rows(_lines(tmp_path)))
    assert _associate(tmp_path, 'bad.csv', '--skip-invalid') == 0
    captured = capsys.readouterr()
    assert 'warning: 2 invalid row(s) skipped' in captured.err
    rows = _out_rows(tmp_path)
    assert len(rows) == len(clean) + 2
    assert list(rows[0])[-2:] == ['track_id', 'rejected']
    assert [(r['track_id'], r['rejected']) for r in (rows[1], rows[4])] == [
        ('-1', 'speed_out_of_range'),
        ('-1', 'stamp_out_of_range'),
    ]
    assert rows[1]['velocity_mps'] == '1e308' and rows[4]['stamp_s'] == '1e300'
    kept = [r for i, r in enumerate(rows) if i not in (1, 4)]
    assert all(r['rejected'] == '' for r in kept)
    # the valid rows are exactly the clean file: same tracks, same accuracy
    assert [r['track_id'] for r in kept] == clean
    accuracy_line = re.search(r'accuracy: .*', clean_out).group(0)
    assert accuracy_line in captured.out


def test_bounds_options_move_the_limits(tmp_path, capsys):
    _write(tmp_path / 'in.csv')
    lines = _lines(tmp_path)
    early = lines[5].split(',')
    early[2] = '-2.5'
    lines[5] = ','.join(early)
    _save(tmp_path, lines)
    assert _associate(tmp_path, 'bad.csv', '--min-stamp', '0') == 2
    assert 'line 6: stamp_s -2.5 is outside [0, 1e+12] s' in capsys.readouterr().err
    assert _associate(tmp_path, 'bad.csv', '--min-stamp', '-2.5') == 0
    assert _associate(tmp_path, 'bad.csv', '--max-speed', '20') == 2
    assert 'outside [0.01, 20] m/s (--min-speed/--max-speed)' in capsys.readouterr().err
    assert _associate(tmp_path, 'bad.csv', '--min-speed', '5', '--max-speed', '4') == 2
    assert 'invalid bounds' in capsys.readouterr().err


def test_duplicate_rows_are_refused_or_skipped(tmp_path, capsys):
    _write(tmp_path / 'in.csv')
    lines = _lines(tmp_path)
    _save(tmp_path, [*lines, lines[7]])  # line 8 again, as the last line
    assert _associate(tmp_path, 'bad.csv') == 2
    err = capsys.readouterr().err
    assert f'line {len(lines) + 1}: duplicate of line 8' in err
    assert _associate(tmp_path, 'bad.csv', '--skip-invalid') == 0
    rows = _out_rows(tmp_path)
    assert (rows[-1]['track_id'], rows[-1]['rejected']) == ('-1', 'duplicate')
    assert rows[6]['rejected'] == '' and int(rows[6]['track_id']) >= 0


def test_lane_and_length_columns_are_read_and_keyed(tmp_path, capsys):
    _write(tmp_path / 'in.csv')
    lines = _lines(tmp_path)
    with_lane = [lines[0] + ',lane,length_m'] + [f'{r},0,4.5' for r in lines[1:]]
    # the same sensor and stamp on another lane is another vehicle, not a duplicate
    with_lane.append(lines[7] + ',1,')
    _save(tmp_path, with_lane)
    layout, dets, rows, header = read_detections(tmp_path / 'bad.csv')
    assert header[-2:] == ['lane', 'length_m']
    assert dets.lane.tolist() == [0] * (len(lines) - 1) + [1]
    assert np.isnan(dets.length[-1]) and dets.length[0] == 4.5
    assert _associate(tmp_path, 'bad.csv') == 0
    _save(tmp_path, [*with_lane, lines[7] + ',1,4.0'])
    assert _associate(tmp_path, 'bad.csv') == 2
    assert f'line {len(lines) + 2}: duplicate of line {len(lines) + 1}' in capsys.readouterr().err


def test_output_that_cannot_be_a_file_is_a_clear_error(tmp_path, capsys):
    _write(tmp_path / 'in.csv')
    (tmp_path / 'dir').mkdir()
    rc = main(['associate', '--input', str(tmp_path / 'in.csv'), '--output', str(tmp_path)])
    assert rc == 2
    assert '--output is a directory' in capsys.readouterr().err
    parent_is_file = tmp_path / 'in.csv' / 'out.csv'
    rc = main(['associate', '--input', str(tmp_path / 'in.csv'), '--output', str(parent_is_file)])
    assert rc == 2
    assert 'in.csv is not a directory' in capsys.readouterr().err
    rc = main(
        ['associate', '--input', str(tmp_path / 'in.csv'), '--output', str(tmp_path / 'in.csv')]
    )
    assert rc == 2
    assert '--output is the input file' in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['dir', 'in.csv']


@pytest.mark.parametrize('seed', ['-1', str(2**32), 'x'])
def test_seed_out_of_range_is_a_usage_error(tmp_path, capsys, seed):
    _write(tmp_path / 'in.csv')
    with pytest.raises(SystemExit) as exc:
        _associate(tmp_path, 'in.csv', '--method', 'kmeans_pp', '--seed', seed)
    assert exc.value.code == 2
    assert 'argument --seed' in capsys.readouterr().err
    assert _associate(tmp_path, 'in.csv', '--method', 'kmeans_pp', '--seed', str(2**32 - 1)) == 0


def test_non_utf8_byte_is_reported_on_its_own_line(tmp_path, capsys):
    _write(tmp_path / 'in.csv')
    data = (tmp_path / 'in.csv').read_bytes().split(b'\n')
    data[99] = data[99][:4] + b'\xff' + data[99][5:]  # line 100, deep past the first buffer
    (tmp_path / 'bad.csv').write_bytes(b'\n'.join(data))
    assert _associate(tmp_path, 'bad.csv') == 2
    err = capsys.readouterr().err
    assert 'bad.csv: line 100: not UTF-8 text (byte 0xff at column 5)' in err


def test_many_targets_are_scored_without_a_dense_table(tmp_path, capsys):
    # 20,000 targets over two sensors: a dense track x target table and its Hungarian
    # assignment would need GBs and hours; the sparse matching needs neither.
    ds = simulate(SimConfig(n_targets=20_000, n_sensors=2, start_increment_min=0.0), 3)
    d = ds.detections
    pos = ds.layout.positions.tolist()
    lines = [HEADER] + [
        f'{k},{pos[k]!r},{t!r},{v!r},{g}'
        for k, t, v, g in zip(d.sensor_index.tolist(), d.stamp.tolist(), d.velocity.tolist(),
                              d.target.tolist(), strict=True)
    ]  # fmt: skip
    _save(tmp_path, lines, 'in.csv')
    assert _associate(tmp_path, 'in.csv', '--method', 'assignment') == 0
    out = capsys.readouterr().out
    rows = _out_rows(tmp_path)
    from mlkm_core.metrics import accuracy

    acc = accuracy(
        np.array([int(r['track_id']) for r in rows]), np.array([int(r['target_id']) for r in rows])
    )
    assert acc.total == 40_000 and acc.accuracy > 0.9
    assert f'accuracy: {100 * acc.accuracy:.2f} % ({acc.correct}/40000)' in out


def test_progress_goes_to_stderr_only_when_asked(tmp_path, capsys):
    _write(tmp_path / 'in.csv')
    assert _associate(tmp_path, 'in.csv') == 0
    quiet = capsys.readouterr()
    assert quiet.err == ''  # not a terminal: no bars in pipes
    plain = (tmp_path / 'out.csv').read_text()
    for method in ('mlkm', 'kmeans_pp'):
        assert _associate(tmp_path, 'in.csv', '--progress', '--method', method) == 0
        shown = capsys.readouterr()
        assert 'reading' in shown.err and f'associating ({method})' in shown.err
        assert 'writing' in shown.err and 'associating' not in shown.out
    # the per-segment path gives the very tracks of the batch run
    assert _associate(tmp_path, 'in.csv', '--progress') == 0
    assert (tmp_path / 'out.csv').read_text() == plain
    assert _timeless(capsys.readouterr().out) == _timeless(quiet.out)


def _timeless(text: str) -> str:
    """The CLI's report without its run times, which vary from run to run."""
    return re.sub(r'\d+(\.\d+)? s\b', '<t> s', text)


def test_input_far_beyond_a_methods_size_gets_a_warning(tmp_path, capsys, monkeypatch):
    _write(tmp_path / 'in.csv')
    monkeypatch.setitem(cli.COMFORTABLE, 'kmeans_pp', 10)
    assert _associate(tmp_path, 'in.csv', '--method', 'kmeans_pp') == 0
    err = capsys.readouterr().err
    assert 'far beyond what kmeans_pp handles' in err and '--method assignment' in err
    assert _associate(tmp_path, 'in.csv', '--method', 'mlkm') == 0
    assert capsys.readouterr().err == ''


def test_stream_writes_the_committed_labels_of_the_streaming_core(tmp_path, capsys):
    from mlkm_core.metrics import accuracy
    from mlkm_core.streaming import StreamConfig, StreamTracker

    ds = _write(tmp_path / 'in.csv', seed=2)
    rc = _associate(tmp_path, 'in.csv', '--method', 'multiframe', '--stream', '--lag', '8')
    assert rc == 0
    out = capsys.readouterr().out
    assert '(multiframe, stream, lag 8 s,' in out
    assert re.search(r'revision rate: \d+\.\d\d % \(\d+ of \d+ first-published links', out)
    assert 'commit latency (stamp time): median' in out
    rows = _out_rows(tmp_path)
    tracks = np.array([int(r['track_id']) for r in rows])
    # the same labels as pushing the rows in stamp order through the core (key = row)
    d = ds.detections
    tracker = StreamTracker(ds.layout, StreamConfig(method='multiframe', lag=8.0))
    expected = np.full(len(d), -2)
    updates = [
        tracker.push(i, int(d.sensor_index[i]), float(d.stamp[i]), float(d.velocity[i]))
        for i in np.lexsort((np.arange(len(d)), d.sensor_index, d.stamp)).tolist()
    ]
    for u in [*updates, tracker.flush()]:
        expected[u.committed[:, 0]] = u.committed[:, 1]
    assert np.array_equal(tracks, expected)
    acc = accuracy(tracks, d.target)
    assert acc.accuracy > 0.95 and f'accuracy: {100 * acc.accuracy:.2f} %' in out


def test_stream_takes_ramp_positions_and_refuses_bad_ones(tmp_path, capsys):
    _write(tmp_path / 'in.csv')
    rc = _associate(
        tmp_path, 'in.csv', '--method', 'assignment', '--stream', '--exits', '150.5, 300'
    )
    assert rc == 0 and 'revision rate:' in capsys.readouterr().out
    for bad in ('x', 'nan', '-3'):
        with pytest.raises(SystemExit) as exc:
            _associate(tmp_path, 'in.csv', '--stream', '--entries', bad)
        assert exc.value.code == 2
    assert _associate(tmp_path, 'in.csv', '--stream', '--lag', '0') == 2
    assert 'lag must be a finite number > 0' in capsys.readouterr().err


def test_sumo_subcommand_hands_its_arguments_to_mlkm_sumo(capsys):
    pytest.importorskip('mlkm_sumo')
    assert main(['sumo', '--help']) == 0
    assert 'usage: mlkm sumo' in capsys.readouterr().out
    assert main(['sumo', '--scenario', 'nope', '--output', 'x.csv']) == 2
    assert "mlkm sumo: error: unknown scenario 'nope'" in capsys.readouterr().err


def test_batch_associators_take_the_ramp_positions(tmp_path, capsys):
    # SUMO ramps (20 vehicles, 8 stations, seed 1) with time and speed only: told where
    # vehicles can join and leave, multiframe no longer joins a vehicle that took the
    # off-ramp with one that came up the next on-ramp (97.16 % -> 99.29 %, measured)
    from mlkm_sumo.api import generate

    ds = generate('ramps', 20, 8, 1, cache_dir=tmp_path / 'networks')
    d, pos = ds.detections, ds.layout.positions
    lines = [HEADER] + [
        f'{k},{float(pos[k])!r},{float(t)!r},{float(v)!r},{g}'
        for k, t, v, g in zip(d.sensor_index, d.stamp, d.velocity, d.target)
    ]
    (tmp_path / 'in.csv').write_text('\n'.join(lines) + '\n')
    on = ','.join(str(r.position) for r in ds.road.ramps if r.kind == 'on')
    off = ','.join(str(r.position) for r in ds.road.ramps if r.kind == 'off')
    assert (on, off) == ('1200.0,3200.0', '2300.0,4300.0')
    n = str(ds.n_targets)
    assert _associate(tmp_path, 'in.csv', '--method', 'multiframe', '--targets', n) == 0
    closed = capsys.readouterr().out
    tracks_closed = [r['track_id'] for r in _out_rows(tmp_path)]
    argv = ['--method', 'multiframe', '--targets', n, '--entries', on, '--exits', off]
    assert _associate(tmp_path, 'in.csv', *argv) == 0
    open_road = capsys.readouterr().out
    assert [r['track_id'] for r in _out_rows(tmp_path)] != tracks_closed
    assert 'accuracy: 97.16 % (137/141)' in closed
    assert 'accuracy: 99.29 % (140/141)' in open_road


def _labels(tmp_path, name, *extra):
    """(track ids of the rows, printed accuracy line) of ``mlkm associate`` on ``name``."""
    rc = main(
        [
            'associate',
            '--input',
            str(tmp_path / name),
            '--output',
            str(tmp_path / f'{name}.out'),
            *extra,
        ]
    )
    assert rc == 0
    with open(tmp_path / f'{name}.out') as f:
        return [r['track_id'] for r in csv.DictReader(f)]


def test_two_vehicles_at_one_stamp_without_lane_are_both_kept(tmp_path, capsys):
    # Two vehicles cross the first station in the same millisecond, in lanes the file does
    # not give, at different speeds: two reports, as the node keeps them (duplicate_key).
    ds = _write(tmp_path / 'in.csv')
    d = ds.detections
    i, j = np.flatnonzero(d.sensor_index == 0)[:2]
    delta = d.stamp[i] - d.stamp[j]  # vehicle j, all along the road, delta earlier
    lines = _lines(tmp_path)
    for k in np.flatnonzero(d.target == d.target[j]):
        row = lines[1 + k].split(',')
        row[2] = repr(float(d.stamp[k] + delta))
        lines[1 + k] = ','.join(row)
    a, b = lines[1 + i].split(','), lines[1 + j].split(',')
    assert a[:3] == b[:3] and a[3] != b[3]
    _save(tmp_path, lines)
    tracks = _labels(tmp_path, 'bad.csv', '--method', 'assignment')
    assert len(tracks) == len(d)
    assert 'accuracy: 100.00 %' in capsys.readouterr().out
    # each row keeps its own label: the output is keyed by row, not by (sensor, stamp)
    assert tracks[i] != tracks[j] and min(int(tracks[i]), int(tracks[j])) >= 0
    # the same report twice (same sensor, stamp and velocity, lane unknown) is a duplicate
    _save(tmp_path, [*lines, lines[1 + i]])
    assert _associate(tmp_path, 'bad.csv') == 2
    err = capsys.readouterr().err
    assert f'line {len(lines) + 1}: duplicate of line {i + 2}' in err
    assert 'same sensor_id, stamp_s and velocity_mps, lane unknown' in err


@pytest.mark.parametrize(
    'method,extra',
    [('mlkm', []), ('assignment', []), ('multiframe', []), ('multiframe', ['--stream'])],
)
def test_negative_relative_stamps_give_the_labels_of_the_unshifted_file(
    tmp_path, capsys, method, extra
):
    # stamps measured from an event: the same traffic 100 s earlier, half of it before 0
    config = SimConfig(n_targets=20, n_sensors=10, miss_probability=0.05, false_alarm_rate=0.02)
    ds = simulate(config, 3)
    d = ds.detections
    for name, shift in (('a.csv', 0.0), ('b.csv', -100.0)):
        lines = [HEADER]
        for i in range(len(d)):
            k = d.sensor_index[i]
            stamp = round(float(d.stamp[i]), 3) + shift
            lines.append(
                f'{k},{float(ds.layout.positions[k])!r},{stamp:.3f},'
                f'{float(d.velocity[i])!r},{d.target[i]}'
            )
        _save(tmp_path, lines, name)
    assert any(line.split(',')[2].startswith('-') for line in _lines(tmp_path, 'b.csv'))
    plain = _labels(tmp_path, 'a.csv', '--method', method, *extra)
    plain_out = capsys.readouterr().out
    shifted = _labels(tmp_path, 'b.csv', '--method', method, *extra)
    shifted_out = capsys.readouterr().out
    assert shifted == plain
    accuracy = re.search(r'accuracy: .*', plain_out).group(0)
    assert accuracy in shifted_out


def test_a_stamp_that_is_not_finite_is_refused_naming_line_and_column(tmp_path, capsys):
    _write(tmp_path / 'in.csv')
    lines = _lines(tmp_path)
    row = lines[3].split(',')
    row[2] = 'nan'
    lines[3] = ','.join(row)
    _save(tmp_path, lines)
    assert _associate(tmp_path, 'bad.csv') == 2
    assert 'line 4: stamp_s must be finite, got nan' in capsys.readouterr().err


def test_a_station_at_the_road_origin_is_accepted(tmp_path, capsys):
    ds = _write(tmp_path / 'in.csv')
    origin = float(ds.layout.positions[0])
    lines = _lines(tmp_path)
    moved = [lines[0]]
    for line in lines[1:]:
        row = line.split(',')
        row[1] = repr(float(row[1]) - origin)  # the first station at 0.0
        moved.append(','.join(row))
    _save(tmp_path, moved, 'origin.csv')
    assert '100,0.0,' in (tmp_path / 'origin.csv').read_text()
    plain = _labels(tmp_path, 'in.csv')
    plain_out = capsys.readouterr().out
    assert _labels(tmp_path, 'origin.csv') == plain
    accuracy = re.search(r'accuracy: .*', plain_out).group(0)
    assert accuracy in capsys.readouterr().out


def test_a_misspelt_optional_column_is_named_and_copied(tmp_path, capsys):
    _write(tmp_path / 'in.csv')
    lines = _lines(tmp_path)
    _save(tmp_path, [lines[0] + ',lenght_m'] + [f'{r},4.5' for r in lines[1:]])
    tracks = _labels(tmp_path, 'bad.csv')
    err = capsys.readouterr().err
    assert "unknown column 'lenght_m' is not read" in err and 'did you mean length_m?' in err
    rows = list(csv.DictReader(open(tmp_path / 'bad.csv.out')))
    assert [r['lenght_m'] for r in rows] == ['4.5'] * len(tracks)
