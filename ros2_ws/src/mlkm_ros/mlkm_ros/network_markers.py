"""/mlkm/markers on a road network: its links, stations and tracks in the network's plane.

Frame ``road`` is then the plane of the links' shapes (``RoadLink.shape``: x east, y north
[m], SUMO's coordinates for a SUMO network), z up. A link is a grey line along its shape; a
station is a pole at its point of its link, with its name above it; a track is a sphere on
the link of its latest detection, at that station's position plus the track's last speed
times the time since, clamped to the next station on that link or the link's end (where the
vehicle is seen next on another link, the sphere moves there), coloured by its id as on one
road. A network whose links have no shape has nothing to place: ``network_geometry`` is None
and the node draws nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from geometry_msgs.msg import Point
from visualization_msgs.msg import Marker, MarkerArray

from mlkm_core.network import RoadNetwork
from mlkm_ros.markers import (
    TrackView,
    clear_all,
    new_marker,
    rgba,
    text_marker,
    track_markers,
    track_position,
)
from mlkm_ros.stamps import ns_to_time


@dataclass(frozen=True)
class NetworkGeometry:
    """Where a network's links and stations lie (plain values)."""

    network: RoadNetwork
    links: dict  # link id -> RoadLink
    station_xy: tuple[tuple[float, float], ...]  # per station index [m]
    limits: tuple[float, ...]  # per station: the next station on its link, or its end [m]
    size: float  # marker size [m], from the network's extent

    def place(self, station: int, stamp: float, speed: float, now: float) -> tuple:
        """(x [m], y [m], reached): where a track last seen at ``station`` at ``stamp`` [s]
        with ``speed`` [m/s] is at stamp time ``now`` [s] (module docstring); ``reached``:
        it stands at its clamp."""
        net = self.network
        offset = float(net.station_offsets[station])
        limit = self.limits[station]
        along = track_position(offset, stamp, speed, now, limit)
        x, y, _ = self.links[int(net.station_links[station])].point_at(along)
        return x, y, along >= limit


def network_geometry(net: RoadNetwork) -> NetworkGeometry | None:
    """The geometry of ``net``; None when a link has no shape (nothing can be placed)."""
    if not all(k.shape for k in net.links):
        return None
    links = {k.link_id: k for k in net.links}
    xy, limits = [], []
    for s in range(net.n_stations):
        link = links[int(net.station_links[s])]
        offset = float(net.station_offsets[s])
        xy.append(link.point_at(offset)[:2])
        ahead = [x for x, _ in net.stations_along[link.link_id] if x > offset]
        limits.append(min(ahead, default=link.length))
    points = [p for k in net.links for p in k.shape]
    extent = max(
        max(p[0] for p in points) - min(p[0] for p in points),
        max(p[1] for p in points) - min(p[1] for p in points),
    )
    return NetworkGeometry(net, links, tuple(xy), tuple(limits), max(1.0, extent / 250.0))


def build_network_markers(
    geometry: NetworkGeometry,
    stamp_ns: int,
    tracks: Sequence[TrackView],
    status: str = '',
) -> MarkerArray:
    """The MarkerArray of a network (module docstring): links, stations, tracks, status."""
    stamp = ns_to_time(max(0, int(stamp_ns)))
    size = geometry.size
    net = geometry.network
    out = [clear_all(stamp)]
    for i, link in enumerate(net.links):
        line = new_marker('links', i, Marker.LINE_STRIP, stamp, 0, 0, 0, rgba(0.6, 0.6, 0.6))
        line.points = [Point(x=float(x), y=float(y)) for x, y in link.shape]
        line.scale.x = size / 4.0
        out.append(line)
    for i, ((x, y), name) in enumerate(zip(geometry.station_xy, net.station_names, strict=True)):
        pole = new_marker(
            'stations', i, Marker.CYLINDER, stamp, x, y, 1.5 * size, rgba(0.4, 0.55, 0.8)
        )
        pole.scale.x = pole.scale.y = size / 2.0
        pole.scale.z = 3.0 * size
        out.append(pole)
        out.append(text_marker('station_names', i, stamp, x, 4.0 * size, name, size, y))
    if status:
        x0 = min(p[0] for k in net.links for p in k.shape)
        y0 = max(p[1] for k in net.links for p in k.shape)
        out.append(text_marker('status', 0, stamp, x0, 6.0 * size, status, 1.5 * size, y0))
    out.extend(track_markers(tracks, stamp, size))
    return MarkerArray(markers=out)
