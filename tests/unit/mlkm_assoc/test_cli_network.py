"""``mlkm associate --layout network.yaml``: a detections CSV on a hand-made road network."""

from __future__ import annotations

import csv

import pytest

from mlkm_assoc.cli import main

# link 0 (1000 m) diverges into links 1 and 2; stations 10 and 11 on link 0, 12 on link 1,
# 13 on link 2 (stations 10 and 13 stand at the same position along their own links)
LAYOUT = """\
links:
  - {id: 0, length_m: 1000.0}
  - {id: 1, length_m: 600.0}
  - {id: 2, length_m: 600.0}
connections:
  - {from: 0, to: 1}
  - {from: 0, to: 2}
stations:
  - {id: 10, link: 0, position_m: 300.0}
  - {id: 11, link: 0, position_m: 800.0}
  - {id: 12, link: 1, position_m: 200.0}
  - {id: 13, link: 2, position_m: 300.0}
"""
HEADER = 'sensor_id,position_m,stamp_s,velocity_mps,target_id'
# A (20 m/s) turns onto link 1; B (25 m/s) overtakes it and turns onto link 2
ROWS = [
    '10,300.0,0.0,20.0,0', '11,800.0,25.0,20.0,0', '12,200.0,45.0,20.0,0',
    '10,300.0,2.0,25.0,1', '11,800.0,22.1,25.0,1', '13,300.0,42.1,25.0,1',
]  # fmt: skip
ASSIGNMENT = ['--method', 'assignment']


def write(tmp_path, rows=ROWS, layout=LAYOUT):
    (tmp_path / 'net.yaml').write_text(layout)
    (tmp_path / 'in.csv').write_text('\n'.join([HEADER, *rows]) + '\n')
    return ['associate', '--input', str(tmp_path / 'in.csv'), '--layout',
            str(tmp_path / 'net.yaml'), '--output', str(tmp_path / 'out.csv')]  # fmt: skip


@pytest.mark.parametrize('method', ['assignment', 'gmlkm'])
def test_each_vehicle_is_one_track_across_the_diverge(tmp_path, capsys, method):
    assert main([*write(tmp_path), '--method', method]) == 0
    out = capsys.readouterr().out
    assert f'6 detections from 4 sensors -> 2 tracks ({method}, road network of 3 links' in out
    assert 'accuracy: 100.00 % (6/6)' in out
    with open(tmp_path / 'out.csv') as f:
        rows = list(csv.DictReader(f))
    track = {}
    for r in rows:
        track.setdefault(r['target_id'], set()).add(r['track_id'])
    assert len(track['0']) == len(track['1']) == 1 and track['0'] != track['1']


@pytest.mark.parametrize(
    ('rows', 'extra', 'message'),
    [
        (['14,300.0,0.0,20.0,0'], ASSIGNMENT, 'line 2: sensor 14 is not a station of the network'),
        (['12,300.0,0.0,20.0,0'], ASSIGNMENT, 'line 2: sensor 12 at position_m 300.0, but the '
         'network puts it at 200 m along link 1'),
        (ROWS, ['--method', 'mlkm'], '--method mlkm does not associate road networks'),
        (ROWS, ['--method', 'gmlkm', '--stream'],
         '--stream on a road network links with --method assignment'),
        (ROWS, ['--method', 'assignment', '--targets', '2'], '--targets: not with --layout'),
    ],
)  # fmt: skip
def test_what_does_not_fit_the_network_is_refused(tmp_path, capsys, rows, extra, message):
    assert main([*write(tmp_path, rows), *extra]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / 'out.csv').exists()


def test_the_network_stream_through_the_cli(tmp_path, capsys):
    assert main([*write(tmp_path), '--method', 'assignment', '--stream']) == 0
    out = capsys.readouterr().out
    assert (
        '6 detections from 4 sensors -> 2 tracks (assignment, road network of 3 links, '
        'stream, lag 15 s' in out
    )
    assert 'accuracy: 100.00 % (6/6)' in out
    # the two first detections started tracks of their own before any model was fitted;
    # the first window left them alone, then the immediate links joined them to their vehicle
    assert 'revision rate: 33.33 % (2 of 6 first-published links changed' in out


def test_a_network_method_needs_the_layout(tmp_path, capsys):
    argv = write(tmp_path)
    cut = argv.index('--layout')
    assert main([*argv[:cut], *argv[cut + 2 :], '--method', 'gmlkm']) == 2
    assert '--method gmlkm associates road networks' in capsys.readouterr().err


def test_a_broken_layout_file_is_refused_with_its_entry(tmp_path, capsys):
    broken = LAYOUT.replace('{from: 0, to: 2}', '{from: 0, to: 7}')
    assert main([*write(tmp_path, layout=broken), '--method', 'assignment']) == 2
    assert 'net.yaml' in capsys.readouterr().err


def test_network_rows_without_the_layout_are_refused_with_a_hint(tmp_path, capsys):
    """Stations 10 and 13 stand at 300 m along their own links: read as one road they would
    be one place; the error says which layout the rows need."""
    argv = write(tmp_path)
    cut = argv.index('--layout')
    assert main([*argv[:cut], *argv[cut + 2 :], *ASSIGNMENT]) == 2
    err = capsys.readouterr().err
    assert 'sensors 10 and 13 share position_m 300.0' in err
    assert 'give its layout file, --layout' in err
    assert not (tmp_path / 'out.csv').exists()
