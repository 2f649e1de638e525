"""/mlkm/markers: the road, its stations, their latest detections and the tracks placed along
the road, as a ``visualization_msgs/MarkerArray`` in frame ``road``.

Frame ``road`` (REP-103 axes): x along the road from its start [m], y to the left of the
direction of travel [m], z up [m]. The road is a line from x = 0 to its length; a station is
a pole at its position with its name above it; a station's recent detections are spheres to
the right of the road (one row per lane); a track is a sphere on the road, coloured by its id
(the same colour for the same id in every message), with its id as text above it.

Each array starts with a DELETEALL marker and then holds the whole picture, so a track that is
gone vanishes from the display at the next array. Marker ids are stable: a station's markers
have its index, a track's markers ``track_id mod 2^31``.

The geometry (:func:`track_position`, :func:`next_station`) and the colours are plain
functions; :func:`build_markers` turns a :class:`Scene` (plain values) into the message.
"""

from __future__ import annotations

import bisect
import colorsys
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from mlkm_ros.stamps import ns_to_time

#: The frame every marker is in (x along the road [m]).
FRAME = 'road'
#: Marker ids are int32: a track's markers get ``track_id % ID_MODULUS``.
ID_MODULUS = 2**31
#: Alpha of a track whose links may still be revised (stream mode) [-].
REVISABLE_ALPHA = 0.35


def next_station(positions: Sequence[float], position: float, road_length: float) -> float:
    """Position [m] of the first station strictly past ``position`` (``positions`` sorted),
    or the road's end when there is none."""
    i = bisect.bisect_right(positions, position)
    return float(positions[i]) if i < len(positions) else float(road_length)


def track_position(
    last_position: float, last_stamp: float, speed: float, now: float, limit: float
) -> float:
    """Where a track is at stamp time ``now`` [s]: its last station ``last_position`` [m]
    plus its last ``speed`` [m/s] times the time since its last detection ``last_stamp`` [s],
    never before that station nor past ``limit`` [m] (the next station, or the road's end).
    A speed that is not a positive finite number keeps the track at its last station."""
    if not (math.isfinite(speed) and speed > 0.0):
        return last_position
    elapsed = max(0.0, now - last_stamp)
    return min(max(last_position + speed * elapsed, last_position), max(limit, last_position))


def track_colour(track_id: int) -> tuple[float, float, float]:
    """A bright colour (r, g, b in [0, 1]) of a track id: the same id always gets the same
    colour, and consecutive ids get far-apart hues (Knuth's multiplicative hash)."""
    hue = ((int(track_id) * 2654435761) % 2**32) / 2**32
    return colorsys.hsv_to_rgb(hue, 0.85, 0.95)


def marker_id(track_id: int) -> int:
    """The int32 marker id of a track."""
    return int(track_id) % ID_MODULUS


@dataclass(frozen=True)
class TrackView:
    """One track as drawn: its id, where it is [m], and whether every link is committed
    (None in episodes mode, where that question does not arise)."""

    track_id: int
    x: float  # [m]
    committed: bool | None = None
    y: float = 0.0  # [m] (a road network's plane; 0 on one road)


@dataclass
class Scene:
    """Everything one MarkerArray shows (plain values)."""

    stamp_ns: int  # the graph's latest detection stamp [ns]
    road_length: float  # [m]
    positions: Sequence[float]  # station positions, sorted [m]
    names: Sequence[str]  # station names, parallel to positions
    # per station: (lane, velocity [m/s]) of its recent detections, newest last
    detections: Sequence[Sequence[tuple[int, float]]] = ()
    tracks: Sequence[TrackView] = ()
    status: str = ''  # a line of text at the road's start (episode, segments, mode)
    size: float = field(default=0.0)  # marker size [m]; 0 = from the road length

    def marker_size(self) -> float:
        """Marker size [m]: visible on the whole road when it is framed in the view."""
        return self.size if self.size > 0 else max(1.0, self.road_length / 250.0)


def rgba(r: float, g: float, b: float, a: float = 1.0) -> ColorRGBA:
    return ColorRGBA(r=float(r), g=float(g), b=float(b), a=float(a))


def new_marker(
    ns: str, mid: int, kind: int, stamp: Time, x: float, y: float, z: float, colour: ColorRGBA
) -> Marker:
    m = Marker(ns=ns, id=mid, type=kind, action=Marker.ADD, color=colour)
    m.header.frame_id = FRAME
    m.header.stamp = stamp
    m.pose.position.x, m.pose.position.y, m.pose.position.z = float(x), float(y), float(z)
    m.pose.orientation.w = 1.0
    return m


def text_marker(
    ns: str, mid: int, stamp: Time, x: float, z: float, text: str, height: float, y: float = 0.0
) -> Marker:
    m = new_marker(ns, mid, Marker.TEXT_VIEW_FACING, stamp, x, y, z, rgba(1, 1, 1))
    m.text = text
    m.scale.z = float(height)
    return m


def clear_all(stamp: Time | None = None) -> Marker:
    """The DELETEALL marker: a display drops every marker of the topic."""
    clear = Marker(action=Marker.DELETEALL)
    clear.header.frame_id = FRAME
    if stamp is not None:
        clear.header.stamp = stamp
    return clear


def build_markers(scene: Scene) -> MarkerArray:
    """The MarkerArray of ``scene`` (see the module's docstring for what it draws)."""
    stamp = ns_to_time(max(0, int(scene.stamp_ns)))
    size = scene.marker_size()
    out = [clear_all(stamp)]

    road = new_marker('road', 0, Marker.LINE_STRIP, stamp, 0, 0, 0, rgba(0.6, 0.6, 0.6))
    road.points = [Point(), Point(x=float(scene.road_length))]
    road.scale.x = size / 4.0
    out.append(road)
    if scene.status:
        out.append(text_marker('status', 0, stamp, 0.0, 6.0 * size, scene.status, 1.5 * size))

    for i, (x, name) in enumerate(zip(scene.positions, scene.names, strict=True)):
        pole = new_marker(
            'stations', i, Marker.CYLINDER, stamp, x, 0, 1.5 * size, rgba(0.4, 0.55, 0.8)
        )
        pole.scale.x = pole.scale.y = size / 2.0
        pole.scale.z = 3.0 * size
        out.append(pole)
        out.append(text_marker('station_names', i, stamp, x, 4.0 * size, name, size))

    for i, dets in enumerate(scene.detections):
        if not dets:
            continue
        x = scene.positions[i]
        spheres = new_marker('detections', i, Marker.SPHERE_LIST, stamp, x, 0, 0, rgba(1, 0.6, 0))
        spheres.scale.x = spheres.scale.y = spheres.scale.z = 0.6 * size
        # newest nearest to the road, one row per lane (lane 0, the rightmost, first)
        spheres.points = [
            Point(x=-0.7 * size * k, y=-size * (1.0 + max(lane, 0)))
            for k, (lane, _) in enumerate(reversed(dets))
        ]
        out.append(spheres)

    out.extend(track_markers(scene.tracks, stamp, size))
    return MarkerArray(markers=out)


def track_markers(tracks: Sequence[TrackView], stamp: Time, size: float) -> list[Marker]:
    """A sphere per track, coloured by its id (faint while revisable), with its id above."""
    out = []
    for track in tracks:
        mid = marker_id(track.track_id)
        alpha = REVISABLE_ALPHA if track.committed is False else 1.0
        r, g, b = track_colour(track.track_id)
        colour = rgba(r, g, b, alpha)
        dot = new_marker('tracks', mid, Marker.SPHERE, stamp, track.x, track.y, 0, colour)
        dot.scale.x = dot.scale.y = dot.scale.z = size
        out.append(dot)
        label = str(track.track_id) + (' (revisable)' if track.committed is False else '')
        out.append(
            text_marker('track_ids', mid, stamp, track.x, 1.5 * size, label, 0.8 * size, track.y)
        )
    return out
