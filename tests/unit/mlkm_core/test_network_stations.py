"""The stations of a road network in the live graph's shape (``network_assoc.stations``):
their positions along their own links are accepted where a road's would be refused, the
network method runs behind the Associator interface, its incremental session equals the
batch answer on a hand-made diverge, and a method of one road is refused with the reason."""

from __future__ import annotations

import numpy as np
import pytest

from mlkm_core.associators.base import AssociatorConfig
from mlkm_core.associators.multiframe import MultiFrameAssociator
from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_core.network_assoc import associate_network
from mlkm_core.network_assoc.stations import (
    NetworkAssociator,
    associator_for,
    network_method_problem,
    network_stations,
)
from mlkm_core.types import Detections, Layout

NET = RoadNetwork(
    links=(RoadLink(0, 'main', 1000.0), RoadLink(1, 'left', 600.0), RoadLink(2, 'right', 600.0)),
    connections=((0, 1), (0, 2)),
    station_ids=np.array([20, 21, 22, 23]),
    station_names=('a', 'b', 'c', 'd'),
    station_links=np.array([0, 0, 1, 2]),
    station_offsets=np.array([300.0, 800.0, 200.0, 300.0]),
)


def swap_at_the_diverge() -> Detections:
    # A (20 m/s) turns left, B (25 m/s) passes it after the diverge and turns right
    rows = [(0, 0.0, 20.0, 0), (1, 25.0, 20.0, 0), (2, 45.0, 20.0, 0),
            (0, 2.0, 25.0, 1), (1, 22.1, 25.0, 1), (3, 42.1, 25.0, 1)]  # fmt: skip
    s, t, v, k = (np.array(c) for c in zip(*rows, strict=True))
    return Detections(s.astype(np.int64), t.astype(float), v.astype(float), k.astype(np.int64))


def test_the_stations_keep_their_positions_along_their_links():
    stations = network_stations(NET)
    assert stations.positions.tolist() == [300.0, 800.0, 200.0, 300.0]
    assert stations.sensor_ids.tolist() == [20, 21, 22, 23] and stations.names == NET.station_names
    assert stations.road_length == 1000.0 and stations.network is NET
    assert stations.index_of(np.array([23, 20])).tolist() == [3, 0]
    with pytest.raises(ValueError, match='strictly increasing'):  # not on one road
        Layout(1000.0, stations.positions)


def test_the_network_method_behind_the_associator_interface_incremental_equals_batch():
    d = swap_at_the_diverge()
    stations = network_stations(NET)
    associator = associator_for(stations, 'assignment', AssociatorConfig(segment_size=2))
    assert isinstance(associator, NetworkAssociator)
    batch = associate_network(NET, d, 'assignment')
    assert len(set(zip(batch.tolist(), d.target.tolist()))) == 2 == len(set(batch.tolist()))
    session = associator.session(stations, 2)
    first = np.isin(d.sensor_index, [0, 1])
    session.add_segment(d.subset(np.flatnonzero(first)))
    labels = session.add_segment(d.subset(np.flatnonzero(~first)))
    order = np.concatenate([np.flatnonzero(first), np.flatnonzero(~first)])
    expected = batch[order]
    # the same partition of the detections
    assert len(set(zip(labels.tolist(), expected.tolist()))) == len(set(expected.tolist()))


def test_a_method_of_one_road_is_refused_on_a_network_and_kept_on_a_road():
    assert network_method_problem('assignment') is None
    with pytest.raises(ValueError, match="method 'mlkm' does not associate road networks"):
        associator_for(network_stations(NET), 'mlkm', AssociatorConfig())
    assert isinstance(
        associator_for(network_stations(NET), 'multiframe', AssociatorConfig()),
        NetworkAssociator,
    )  # its network form: each link a road
    road = Layout(1000.0, np.array([100.0, 500.0]))
    assert isinstance(associator_for(road, 'multiframe', AssociatorConfig()), MultiFrameAssociator)
    with pytest.raises(TypeError):
        NetworkAssociator('assignment').associate(road, swap_at_the_diverge(), 2)
