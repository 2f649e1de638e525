"""Network layout files (``mlkm_core.network_file``): both forms read as a network, a round
trip of each, and every refusal naming the file and the entry."""

from __future__ import annotations

import numpy as np
import pytest

from mlkm_core.layout_file import (
    LayoutFileError,
    RoadLayout,
    read_layout_file,
    write_layout_file,
)
from mlkm_core.network import RoadLink, RoadNetwork, network_from_mapping, network_to_mapping
from mlkm_core.network_file import read_network_file, write_network_file
from mlkm_core.types import Layout

# the contract's example, connections and ends partly left to the implicit rule
INTERCHANGE = """# a diverge
links:
  - {id: 0, name: main_in, length_m: 800.0, lanes: 3}
  - {id: 1, name: main_out, length_m: 900, lanes: 3}
  - {id: 2, length_m: 300.0, lanes: 1}
connections:
  - {from: 0, to: 1}
  - {from: 0, to: 2}
entries:
  - {link: 0}
exits:
  - {link: 1}
stations:
  - {id: 0, name: loop_00, link: 0, position_m: 200.0, lanes: 3}
  - {id: 1, name: loop_01, link: 1, position_m: 500.0, lanes: 3}
  - {id: 2, link: 2, position_m: 150}
"""


def test_a_network_file_defaults_filled(tmp_path):
    path = tmp_path / 'net.yaml'
    path.write_text(INTERCHANGE)
    n = read_network_file(path)
    assert [(k.link_id, k.name, k.length, k.lanes) for k in n.links] == [
        (0, 'main_in', 800.0, 3),
        (1, 'main_out', 900.0, 3),
        (2, 'link_2', 300.0, 1),  # default name link_<id>
    ]
    assert n.connections == ((0, 1), (0, 2))
    assert n.entries == ((0, 0.0),)
    assert n.exits == ((1, 900.0), (2, 300.0))  # explicit, then implicit on link 2
    assert n.station_names == ('loop_00', 'loop_01', 'sensor_2')  # default sensor_<id>
    assert n.station_links.tolist() == [0, 1, 2]
    assert n.station_offsets.tolist() == [200.0, 500.0, 150.0]
    assert n.station_lanes.tolist() == [3, 3, 0]
    assert [s.index for s in n.successors(0)] == [2, 1]


def test_network_round_trip_through_a_file(tmp_path):
    n = RoadNetwork(
        links=(RoadLink(3, 'on', 507.2, 2), RoadLink(1, 'b', 0.1 + 0.2), RoadLink(0, 'c', 9.0)),
        connections=((3, 1), (1, 0), (0, 3)),  # a ring: nothing implicit
        station_ids=np.array([5, 0]),
        station_names=('no', 'sensor_0'),  # 'no' must be quoted in YAML
        station_links=np.array([3, 1]),
        station_offsets=np.array([35.601, 0.1 + 0.2]),
        station_lanes=np.array([2, 0]),
        entries=((3, 0.0), (1, 0.1)),
        exits=((0, 9.0),),
    )
    path = tmp_path / 'out.yaml'
    write_network_file(path, n, comment='a ring\nwritten by a test')
    text = path.read_text()
    assert text.startswith('# a ring\n# written by a test\nlinks:\n')
    assert "name: 'no'" in text
    back = read_network_file(path)
    assert back == n
    assert back.station_offsets[1] == 0.1 + 0.2  # exactly


def test_implicit_ends_are_left_out_and_come_back(tmp_path):
    path = tmp_path / 'net.yaml'
    path.write_text(INTERCHANGE)
    n = read_network_file(path)
    data = network_to_mapping(n)
    # the file's explicit entry at link 0's start and exit at link 1's end are the implicit ones
    assert data['entries'] == [] and data['exits'] == []
    assert data['connections'] == [{'from': 0, 'to': 1}, {'from': 0, 'to': 2}]
    assert network_from_mapping(data, 'generated') == n
    out = tmp_path / 'again.yaml'
    write_network_file(out, n)
    assert read_network_file(out) == n


def test_a_single_road_file_reads_as_its_one_link_network(tmp_path):
    layout = Layout(510.0, np.array([50.0, 150.5]), np.array([2, 7]), ('sensor_2', 'loop_b'))
    road = RoadLayout(layout, np.array([0, 3]), (100.0,), ())
    path = tmp_path / 'road.yaml'
    write_layout_file(path, road)
    n = read_network_file(path)
    assert n == RoadNetwork.single_road(road)
    assert n.entries == ((0, 0.0), (0, 100.0)) and n.exits == ((0, 510.0),)
    assert read_layout_file(path).layout.positions.tolist() == [50.0, 150.5]  # unchanged
    # written in the network form, it is the same network and still one road
    out = tmp_path / 'as_network.yaml'
    write_network_file(out, n)
    assert 'links:' in out.read_text()
    back = read_network_file(out)
    assert back == n
    again = back.road_layout()
    assert again.layout.positions.tolist() == [50.0, 150.5] and again.entries == (100.0,)


def test_the_single_road_reader_names_a_network_file(tmp_path):
    path = tmp_path / 'net.yaml'
    path.write_text(INTERCHANGE)
    with pytest.raises(LayoutFileError, match='a road network .links:., not a single road'):
        read_layout_file(path)


LINK = '{id: 0, length_m: 100}'
STATION = '{id: 0, link: 0, position_m: 10}'


def doc(links=f'[{LINK}]', stations=f'[{STATION}]', extra=''):
    return f'links: {links}\nstations: {stations}\n{extra}'


@pytest.mark.parametrize(
    ('text', 'message'),
    [
        (doc(extra='junctions: []\n'), "unknown key 'junctions'"),
        (doc(links='[{id: 0, length: 100}]'), r"links\[0\]: unknown key 'length'"),
        (doc(stations='[{id: 0, link: 0, position: 1}]'), r"stations\[0\]: unknown key 'pos"),
        (doc(links='[{id: 0}]'), r'links\[0\]: length_m must be a finite number > 0, got None'),
        (doc(links='[{id: 0, length_m: -5}]'), r'links\[0\]: length_m must be'),
        (doc(links='[{id: x, length_m: 5}]'), r"links\[0\]: id must be an integer >= 0, got 'x'"),
        (doc(links='[{id: 0, length_m: 5, name: a-b}]'), "name 'a-b' is not a topic name token"),
        (doc(links=f'[{LINK}, {LINK}]'), 'link id 0 is used twice'),
        (doc(links='[]'), 'links: a non-empty list is needed'),
        (doc(stations='[]'), 'stations: a non-empty list is needed'),
        (doc(stations='[{id: 0, link: 0}]'), r'stations\[0\]: position_m must be a finite'),
        (doc(stations='[{id: 0, position_m: 1}]'), r'stations\[0\]: link must be an integer'),
        (doc(stations='[{id: 0, link: 0, position_m: 100.5}]'), 'position 100.5 m is off link 0'),
        (doc(stations='[{id: 0, link: 4, position_m: 1}]'), 'link 4 is not in the network'),
        (
            doc(stations=f'[{STATION}, {{id: 1, link: 0, position_m: 10.0}}]'),
            r'station 1 \(sensor_1\): another station stands on link 0 at 10 m',
        ),
        (
            doc(stations=f'[{STATION}, {{id: 0, link: 0, position_m: 20}}]'),
            'station id 0 is used twice',
        ),
        (doc(extra='connections: [{from: 0, to: 0}]\n'), 'connection 0 -> 0 joins a link to'),
        (doc(extra='connections: [{from: 0, to: 1}]\n'), 'connection 0 -> 1: link 1 is not in'),
        (doc(extra='connections: [{from: 0}]\n'), r'connections\[0\]: to must be an integer'),
        (doc(extra='entries: [{link: 3}]\n'), r'entries\[0\]: link 3 is not one of the links'),
        (doc(extra='exits: [{link: 0, position_m: 101}]\n'), 'exit on link 0 at 101 m: off'),
        (doc(extra='exits: {link: 0}\n'), 'exits: a list is needed'),
        (doc(extra='entries: [[0, 1]]\n'), r'entries\[0\]: expected a mapping'),
        (doc(links='[{id: 0, length_m: 5, shape_m: [[0, 0]]}]'), r'links\[0\]: link 0: a sh'),
        (doc(links='[{id: 0, length_m: 5, shape_m: [1, 2]}]'), 'shape must be a list of'),
        (doc(links='[{id: 0, length_m: 5, shape_m: [[1, 2], [1, 2]]}]'), 'has no length'),
    ],
)
def test_each_refusal_names_the_file_and_entry(tmp_path, text, message):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(LayoutFileError, match=message) as exc:
        read_network_file(path)
    assert str(exc.value).startswith(f'{path}: ')


def test_link_shapes_round_trip_and_place_points_along_the_link(tmp_path):
    text = doc(links='[{id: 0, length_m: 100, shape_m: [[0, 0], [30, 40], [30, 90]]}]')
    path = tmp_path / 'shaped.yaml'
    path.write_text(text)
    n = read_network_file(path)
    link = n.links[0]
    assert link.shape == ((0.0, 0.0), (30.0, 40.0), (30.0, 90.0))
    # the polyline is 100 m long: 25 m along is half the first leg, heading atan2(40, 30)
    x, y, heading = link.point_at(25.0)
    assert (x, y) == pytest.approx((15.0, 20.0)) and heading == pytest.approx(0.9272952)
    assert link.point_at(75.0)[:2] == pytest.approx((30.0, 65.0))
    assert link.point_at(500.0)[:2] == pytest.approx((30.0, 90.0))  # clamped to the end
    write_network_file(tmp_path / 'out.yaml', n)
    assert read_network_file(tmp_path / 'out.yaml') == n
    assert 'shape_m' not in network_to_mapping(read_network_file_text(tmp_path, doc()))['links'][0]


def read_network_file_text(tmp_path, text):
    path = tmp_path / 'plain.yaml'
    path.write_text(text)
    return read_network_file(path)


def test_a_missing_or_broken_file(tmp_path):
    with pytest.raises(LayoutFileError, match=r'none\.yaml: No such file'):
        read_network_file(tmp_path / 'none.yaml')
    path = tmp_path / 'broken.yaml'
    path.write_text('links: [\n')
    with pytest.raises(LayoutFileError, match='not YAML'):
        read_network_file(path)


def test_a_mapping_names_its_source():
    with pytest.raises(LayoutFileError, match=r'^scenario\.net\.xml: stations\[0\]: lanes must'):
        network_from_mapping(
            {'links': [{'id': 0, 'length_m': 5.0}],
             'stations': [{'id': 0, 'link': 0, 'position_m': 1.0, 'lanes': -1}]},
            'scenario.net.xml',
        )  # fmt: skip
