"""``mlkm plot`` on a tracks CSV: the hand-made case drawn to a valid PNG, and bad input; on
a road network the detections of one route at their distance along it."""

import numpy as np
from PIL import Image

from mlkm_assoc import cli
from mlkm_assoc.timespace_plot import DPI, FIGSIZE, _polylines, read_tracks_csv
from mlkm_core.timespace import time_space

# The case of tests/unit/mlkm_core/test_timespace.py as `mlkm associate --output` writes it:
# vehicle 0 one track (10); track 11 ends on vehicle 2 (wrong link); track 12 ends on the
# false alarm (wrong link); vehicle 1's last detection unassigned.
ROWS = """sensor_id,position_m,stamp_s,velocity_mps,target_id,track_id
0,0.0,0.0,25.0,0,10
1,100.0,4.0,25.0,0,10
2,200.0,8.0,25.0,0,10
0,0.0,2.0,25.0,1,11
1,100.0,6.0,25.0,1,11
2,200.0,10.0,25.0,1,-1
0,0.0,3.0,25.0,2,12
1,100.0,7.5,25.0,2,12
2,200.0,11.0,25.0,2,11
2,200.0,12.0,25.0,-1,12
"""


def _assert_png(path):
    with Image.open(path) as image:
        image.verify()
    with Image.open(path) as image:
        assert image.format == 'PNG'
        assert image.size == (round(FIGSIZE[0] * DPI), round(FIGSIZE[1] * DPI))


def test_plot_of_a_tracks_csv_writes_a_png_and_counts_the_figure(tmp_path, capsys):
    tracks, png = tmp_path / 'tracks.csv', tmp_path / 'fig' / 'tracks.png'
    tracks.write_text(ROWS)
    assert cli.main(['plot', '--input', str(tracks), '--output', str(png)]) == 0
    out = capsys.readouterr().out
    assert '10 detections, 3 tracks, 1 unassigned, 6 links, 2 wrong;' in out
    assert str(png) in out
    _assert_png(png)


def test_the_csv_gives_the_hand_made_figure_data_and_one_path_per_track_piece(tmp_path):
    tracks = tmp_path / 'tracks.csv'
    tracks.write_text(ROWS)
    data = read_tracks_csv(tracks)
    assert data.labels.tolist() == [10, 10, 10, 11, 11, -1, 12, 12, 11, 12]
    assert data.stations.tolist() == [0.0, 100.0, 200.0] and data.notes == []
    ts = time_space(data.position, data.stamp, data.labels, data.target)
    red = {tuple(map(tuple, link)) for link in ts.links[ts.wrong].tolist()}
    assert red == {((6.0, 100.0), (11.0, 200.0)), ((7.5, 100.0), (12.0, 200.0))}
    lines, first = _polylines(ts.links, ts.link_track, ~ts.wrong)
    # track 10 one polyline through 3 detections; 11 and 12 keep one link each
    assert [len(line) for line in lines] == [3, 2, 2]
    assert ts.link_track[first].tolist() == [10, 11, 12]
    assert np.array_equal(lines[0], [[0.0, 0.0], [4.0, 100.0], [8.0, 200.0]])


NETWORK = """links:
  - {id: 0, name: main, length_m: 1000}
  - {id: 1, name: left, length_m: 600}
  - {id: 2, name: right, length_m: 600}
connections: [{from: 0, to: 1}, {from: 0, to: 2}]
stations:
  - {id: 0, link: 0, position_m: 300}
  - {id: 1, link: 0, position_m: 800}
  - {id: 2, link: 1, position_m: 200}
  - {id: 3, link: 2, position_m: 300}
"""
# vehicle 0 turns left, vehicle 1 right; positions along each station's own link
NETWORK_ROWS = """sensor_id,position_m,stamp_s,velocity_mps,target_id,track_id
0,300.0,0.0,20.0,0,5
1,800.0,25.0,20.0,0,5
2,200.0,45.0,20.0,0,5
0,300.0,2.0,25.0,1,6
1,800.0,22.1,25.0,1,6
3,300.0,42.1,25.0,1,6
"""


def test_a_network_csv_draws_one_route_at_its_distances(tmp_path, capsys):
    layout, tracks = tmp_path / 'net.yaml', tmp_path / 'tracks.csv'
    layout.write_text(NETWORK)
    tracks.write_text(NETWORK_ROWS)
    from mlkm_core.network_file import read_network_file

    net = read_network_file(layout)
    data = read_tracks_csv(tracks, net, 'main,right')
    # the right branch: station 3 stands 1000 + 300 m along the route; vehicle 0's
    # detection on the left branch is off it
    assert data.position.tolist() == [300.0, 800.0, 300.0, 800.0, 1300.0]
    assert data.labels.tolist() == [5, 5, 6, 6, 6]
    assert data.stations.tolist() == [300.0, 800.0, 1300.0]
    assert data.notes == ['1 detection(s) off the route left out']
    assert read_tracks_csv(tracks, net).position.tolist() == [300.0, 800.0, 1200.0, 300.0,
                                                              800.0]  # fmt: skip
    png = tmp_path / 'route.png'
    args = ['plot', '--input', str(tracks), '--layout', str(layout), '--output', str(png)]
    assert cli.main([*args, '--route', 'main,right']) == 0
    assert '5 detections, 2 tracks, 0 unassigned, 3 links, 0 wrong;' in capsys.readouterr().out
    _assert_png(png)
    assert cli.main([*args, '--route', 'left,right']) == 2
    assert 'no connection joins link left to link right' in capsys.readouterr().err
    assert cli.main(['plot', '--input', str(tracks), '--output', str(png), '--route', 'x']) == 2
    assert '--route needs a road network' in capsys.readouterr().err


def test_bad_input_is_one_error_line_and_nothing_is_written(tmp_path, capsys):
    plain, png = tmp_path / 'detections.csv', tmp_path / 'out.png'
    plain.write_text('\n'.join(line.rsplit(',', 1)[0] for line in ROWS.splitlines()) + '\n')
    assert cli.main(['plot', '--input', str(plain), '--output', str(png)]) == 2
    err = capsys.readouterr().err
    assert err.startswith('mlkm plot: error: ') and 'no track_id column' in err
    tracks = tmp_path / 'tracks.csv'
    tracks.write_text(ROWS.replace('2,200.0,12.0,25.0,-1,12', '2,200.0,12.0,25.0,-1,x'))
    assert cli.main(['plot', '--input', str(tracks), '--output', str(png)]) == 2
    assert 'line 11: track_id is not an integer' in capsys.readouterr().err
    assert cli.main(['plot', '--input', str(tracks), '--output', str(tmp_path / 'a.jpg')]) == 2
    assert '--output must be a .png file' in capsys.readouterr().err
    missing = tmp_path / 'missing_bag'
    assert cli.main(['plot', '--input', str(missing), '--output', str(png)]) == 2
    assert 'mlkm plot: error: ' in capsys.readouterr().err
    assert not png.exists() and not list(tmp_path.glob('.*.tmp'))


def test_100k_detections_make_one_path_per_track_piece_not_per_link():
    """What keeps a big input fast to draw: the collection holds a path per run of correct
    links of one track (at most tracks + wrong links of them), never one per link."""
    rng = np.random.default_rng(0)
    stations, vehicles = np.linspace(0.0, 2000.0, 20), 5000
    entry, speed = rng.uniform(0, 3600, vehicles), rng.uniform(20, 35, vehicles)
    stamp = (entry[:, None] + stations[None, :] / speed[:, None]).ravel()
    target = np.repeat(np.arange(vehicles), stations.size)
    labels = target.copy()
    swapped = rng.random(labels.size) < 0.03
    labels[swapped] = rng.integers(0, vehicles, swapped.sum())
    labels[rng.random(labels.size) < 0.01] = -1
    ts = time_space(np.tile(stations, vehicles), stamp, labels, target)
    assert len(ts.points) + len(ts.crosses) == 100_000 and len(ts.links) > 90_000
    lines, _ = _polylines(ts.links, ts.link_track, ~ts.wrong)
    assert sum(len(line) - 1 for line in lines) == len(ts.links) - ts.n_wrong
    assert len(lines) <= ts.tracks.size + ts.n_wrong < len(ts.links) // 5
