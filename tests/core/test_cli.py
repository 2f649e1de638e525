"""The offline CLI: ``mlkm associate`` on good and malformed CSV files."""

import csv

import numpy as np
import pytest

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
