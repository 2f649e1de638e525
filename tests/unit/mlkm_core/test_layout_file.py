"""Road layout files (``mlkm_core.layout_file``): a round trip and every refusal."""

import numpy as np
import pytest

from mlkm_core.layout_file import LayoutFileError, RoadLayout, read_layout_file, write_layout_file
from mlkm_core.types import Layout

GOOD = """# a hand-written road
road_length_m: 510
stations:
  - {id: 7, name: loop_b, position_m: 150.5, lanes: 3}
  - {id: 2, position_m: 50}
entries_m: [100.0]
exits_m: []
"""


def test_a_hand_written_file_stations_sorted_by_position_defaults_filled(tmp_path):
    path = tmp_path / 'road.yaml'
    path.write_text(GOOD)
    road = read_layout_file(path)
    lay = road.layout
    assert lay.road_length == 510.0
    assert lay.positions.tolist() == [50.0, 150.5]
    assert lay.sensor_ids.tolist() == [2, 7]
    assert lay.names == ('sensor_2', 'loop_b')  # default name sensor_<id>
    assert road.lanes.tolist() == [0, 3]  # default 0 = unknown
    assert (road.entries, road.exits) == ((100.0,), ())


def test_round_trip_with_comment_and_awkward_values(tmp_path):
    layout = Layout(
        np.float64(507.2),  # a numpy scalar, as computed road lengths are
        np.array([35.601, 85.243 + 1e-9, 482.379]),
        np.array([0, 5, 9]),
        ('on', 'sensor_5', 'no'),  # names YAML would read as booleans unquoted
    )
    road = RoadLayout(layout, np.array([3, 3, 2]), (60.0,), (200.0, 300.5))
    path = tmp_path / 'out.yaml'
    write_layout_file(path, road, comment='virtual loops on x.csv\nmlkm loops --at 1,2')
    text = path.read_text()
    assert text.startswith('# virtual loops on x.csv\n# mlkm loops --at 1,2\n')
    back = read_layout_file(path)
    assert back.layout.road_length == 507.2
    assert back.layout.positions.tolist() == layout.positions.tolist()  # exactly
    assert back.layout.sensor_ids.tolist() == [0, 5, 9]
    assert back.layout.names == ('on', 'sensor_5', 'no')
    assert back.lanes.tolist() == [3, 3, 2]
    assert (back.entries, back.exits) == ((60.0,), (200.0, 300.5))


def test_writing_a_name_the_reader_refuses_is_refused(tmp_path):
    road = RoadLayout(Layout(10.0, np.array([1.0]), names=('loop 1',)))
    with pytest.raises(LayoutFileError, match="'loop 1' is not a topic name"):
        write_layout_file(tmp_path / 'x.yaml', road)
    assert not (tmp_path / 'x.yaml').exists()


STATION = '{id: 0, name: a, position_m: 10, lanes: 1}'


@pytest.mark.parametrize(
    ('text', 'message'),
    [
        (f'road_length_m: 100\nstations: [{STATION}]\nramps: []\n', "unknown key 'ramps'"),
        (
            'road_length_m: 100\nstations: [{id: 0, position: 10}]\n',
            r"stations\[0\]: unknown key 'position'",
        ),
        (
            f'road_length_m: 100\nstations: [{STATION}, {{id: 0, name: b, position_m: 20}}]\n',
            'id 0 is used twice',
        ),
        (
            f'road_length_m: 100\nstations: [{STATION}, {{id: 1, name: a, position_m: 20}}]\n',
            "name 'a' is used twice",
        ),
        (
            f'road_length_m: 100\nstations: [{STATION}, {{id: 1, name: b, position_m: 10.0}}]\n',
            'stations 0 and 1 share position_m 10',
        ),
        (
            'road_length_m: 100\nstations: [{id: 0, position_m: 100.5}]\n',
            r'stations\[0\]: position_m 100.5 is off the road \[0, 100\] m',
        ),
        (
            'road_length_m: 100\nstations: [{id: 0, position_m: -1}]\n',
            r'position_m -1 is off the road',
        ),
        (
            'road_length_m: 100\nstations: [{id: 0, name: 1abc, position_m: 1}]\n',
            "name '1abc' is not a topic name token",
        ),
        (
            'road_length_m: 100\nstations: [{id: 0, name: a-b, position_m: 1}]\n',
            "name 'a-b' is not a topic name token",
        ),
        (
            'road_length_m: 100\nstations: [{id: 0, name: on, position_m: 1}]\n',
            'name True is not a topic name token',  # unquoted, YAML reads a boolean
        ),
        ('road_length_m: 100\nstations: [{id: -1, position_m: 1}]\n', 'id must be an integer'),
        ('road_length_m: 100\nstations: [{id: 0, position_m: x}]\n', 'position_m must be a'),
        ('road_length_m: 100\nstations: [{id: 0, position_m: 1, lanes: 1.5}]\n', 'lanes must'),
        ('road_length_m: 0\nstations: [{id: 0, position_m: 0}]\n', 'road_length_m must be > 0'),
        ('road_length_m: 100\nstations: []\n', 'a non-empty list of stations'),
        (f'road_length_m: 100\nstations: [{STATION}]\nexits_m: [101]\n', 'exits_m: 101'),
        ('- just\n- a list\n', 'expected a mapping'),
        ('road_length_m: [100\n', 'not YAML'),
    ],
)
def test_each_refusal_names_the_file_and_entry(tmp_path, text, message):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(LayoutFileError, match=message) as exc:
        read_layout_file(path)
    assert str(exc.value).startswith(str(path))


def test_a_missing_file(tmp_path):
    with pytest.raises(LayoutFileError, match=r'none\.yaml: No such file'):
        read_layout_file(tmp_path / 'none.yaml')
