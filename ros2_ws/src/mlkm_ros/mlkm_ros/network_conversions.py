"""Road networks <-> ``SensorLayout`` messages (the network form of the message).

A ``SensorLayout`` whose ``link_ids`` are empty is a single road, read as always by
``conversions.layout_from_msg``; as a network it is the one-link network of
``RoadNetwork.single_road``. A layout with links is a road network: ``road_length`` 0,
positions along each sensor's link, every entry and exit with its link (the message's
comments). Nodes that know only the single road refuse such a layout (``road_length`` 0).
"""

from __future__ import annotations

import numpy as np

from mlkm_core.layout_file import RoadLayout
from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_ros.conversions import lane_counts_from_msg, layout_from_msg, layout_ramps
from mlkm_ros.stamps import header
from road_sensor_msgs.msg import SensorLayout

#: SensorLayout.road_length of a road network: there is no one road.
NETWORK_ROAD_LENGTH = 0.0


def is_network_msg(msg: SensorLayout) -> bool:
    """Whether the layout describes a road network (links given), not a single road."""
    return len(msg.link_ids) > 0


def network_to_msg(net: RoadNetwork, stamp_ns: int) -> SensorLayout:
    """The network form of ``net`` (also for a network that is a single road: a source of a
    single road publishes ``conversions.layout_to_msg``, which every node reads)."""
    msg = SensorLayout(header=header(stamp_ns), road_length=NETWORK_ROAD_LENGTH)
    msg.sensor_ids = [int(s) for s in net.station_ids]
    msg.sensor_names = list(net.station_names)
    msg.positions = [float(x) for x in net.station_offsets]
    msg.lane_counts = [int(n) for n in net.station_lanes] if net.station_lanes.any() else []
    msg.sensor_links = [int(k) for k in net.station_links]
    msg.link_ids = [k.link_id for k in net.links]
    msg.link_names = [k.name for k in net.links]
    msg.link_lengths = [k.length for k in net.links]
    msg.link_lanes = [k.lanes for k in net.links]
    msg.connection_from = [a for a, _ in net.connections]
    msg.connection_to = [b for _, b in net.connections]
    msg.entry_links = [k for k, _ in net.entries]
    msg.entry_positions = [x for _, x in net.entries]
    msg.exit_links = [k for k, _ in net.exits]
    msg.exit_positions = [x for _, x in net.exits]
    if any(k.shape for k in net.links):
        msg.link_shape_sizes = [len(k.shape) for k in net.links]
        msg.link_shape_x = [x for k in net.links for x, _ in k.shape]
        msg.link_shape_y = [y for k in net.links for _, y in k.shape]
    return msg


def msg_to_network(msg: SensorLayout) -> RoadNetwork:
    """The road network of a layout message, either form (module docstring). Raises
    ValueError with the reason when the message is not a valid layout: for a single road the
    rules of ``layout_from_msg``; for a network, parallel arrays of matching lengths,
    ``road_length`` 0 and the rules of ``RoadNetwork``."""
    if not is_network_msg(msg):
        lanes = lane_counts_from_msg(msg)
        road = RoadLayout(layout_from_msg(msg), lanes, *layout_ramps(msg))
        return RoadNetwork.single_road(road)
    if msg.road_length != NETWORK_ROAD_LENGTH:
        raise ValueError(f'road_length must be 0 on a road network, got {msg.road_length!r}')
    _parallel(msg, 'link_ids', 'link_names', 'link_lengths', 'link_lanes')
    _parallel(msg, 'connection_from', 'connection_to')
    _parallel(msg, 'sensor_ids', 'sensor_names', 'positions', 'sensor_links')
    _parallel(msg, 'entry_links', 'entry_positions')
    _parallel(msg, 'exit_links', 'exit_positions')
    if len(msg.lane_counts) not in (0, len(msg.sensor_ids)):
        raise ValueError(
            f'lane_counts has {len(msg.lane_counts)} entries for {len(msg.sensor_ids)} sensors '
            '(give none or one per sensor)'
        )
    shapes = _shapes(msg)
    return RoadNetwork(
        links=tuple(
            RoadLink(int(i), str(name), float(length), int(lanes), shape)
            for i, name, length, lanes, shape in zip(
                msg.link_ids, msg.link_names, msg.link_lengths, msg.link_lanes, shapes
            )
        ),
        connections=tuple(zip(msg.connection_from, msg.connection_to)),
        station_ids=list(msg.sensor_ids),
        station_names=tuple(msg.sensor_names),
        station_links=list(msg.sensor_links),
        station_offsets=list(msg.positions),
        station_lanes=list(msg.lane_counts) or None,
        entries=tuple(zip(msg.entry_links, msg.entry_positions)),
        exits=tuple(zip(msg.exit_links, msg.exit_positions)),
    )


def _shapes(msg: SensorLayout) -> list[tuple[tuple[float, float], ...]]:
    """Each link's shape (``link_shape_*``; none given: every link without one)."""
    sizes = [int(n) for n in msg.link_shape_sizes]
    if not sizes:
        return [()] * len(msg.link_ids)
    if len(sizes) != len(msg.link_ids):
        raise ValueError(
            f'link_shape_sizes has {len(sizes)} entries for {len(msg.link_ids)} links '
            '(give none or one per link)'
        )
    _parallel(msg, 'link_shape_x', 'link_shape_y')
    if sum(sizes) != len(msg.link_shape_x):
        raise ValueError(
            f'link_shape_sizes add up to {sum(sizes)} points, link_shape_x holds '
            f'{len(msg.link_shape_x)}'
        )
    points = list(zip((float(x) for x in msg.link_shape_x), (float(y) for y in msg.link_shape_y)))
    cuts = np.cumsum([0, *sizes])
    return [tuple(points[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]


def _parallel(msg: SensorLayout, *fields: str) -> None:
    sizes = [len(getattr(msg, f)) for f in fields]
    if len(set(sizes)) > 1:
        shown = ', '.join(f'{f} {n}' for f, n in zip(fields, sizes))
        raise ValueError(f'parallel arrays differ in length: {shown}')
