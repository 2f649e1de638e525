"""Routes through a road network (``mlkm_core.network_route``), what the time-space diagram of
a network draws: the distances along a route computed by hand, the default route, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_core.network_route import main_route, parse_route, route_stations

# 'in' (1000 m, stations at 300 and 800 m) splits into 'left' (600 m, one station at 200 m)
# and 'right' (600 m, stations at 100 and 400 m); 'ramp' (300 m, no station) joins 'right'
NET = RoadNetwork(
    links=(RoadLink(0, 'in', 1000.0), RoadLink(1, 'left', 600.0), RoadLink(2, 'right', 600.0),
           RoadLink(3, 'ramp', 300.0)),
    connections=((0, 1), (0, 2), (3, 2)),
    station_ids=np.array([10, 11, 12, 13, 14]),
    station_names=('a', 'b', 'c', 'd', 'e'),
    station_links=np.array([0, 0, 1, 2, 2]),
    station_offsets=np.array([300.0, 800.0, 200.0, 100.0, 400.0]),
)  # fmt: skip


def test_distances_along_a_route_add_the_links_before():
    assert route_stations(NET, (0, 2)) == {0: 300.0, 1: 800.0, 3: 1100.0, 4: 1400.0}
    assert route_stations(NET, (0, 1)) == {0: 300.0, 1: 800.0, 2: 1200.0}
    assert route_stations(NET, (3, 2)) == {3: 400.0, 4: 700.0}  # the ramp holds none


def test_the_default_route_holds_the_most_stations():
    assert main_route(NET) == (0, 2)  # 4 stations; (0, 1) has 3, (3, 2) 2


def test_routes_by_name_or_id_and_the_refusals():
    assert parse_route(NET, 'in, right') == parse_route(NET, '0,2') == (0, 2)
    with pytest.raises(ValueError, match="no link 'nowhere' in the network"):
        parse_route(NET, 'in,nowhere')
    with pytest.raises(ValueError, match='no connection joins link left to link right'):
        parse_route(NET, 'left,right')
    with pytest.raises(ValueError, match='a link appears twice'):
        route_stations(NET, (0, 0))
