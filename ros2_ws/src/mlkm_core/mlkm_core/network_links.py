"""A link of a road network (``RoadLink``): one directed road section, with its optional shape.

A vehicle drives a link from 0 m to its ``length``. Where the layout knows where the link lies
(SUMO networks do), ``shape`` is its centre line as a polyline in the network's plane (x east,
y north [m]), from the link's start to its end; a position along the link maps onto it in
proportion to the polyline's own length (``point_at``), so a shape drawn a little shorter or
longer than the driven length still places every station on it. No shape: the layout carries
no geometry (the association does not need one; the markers cannot draw the link).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mlkm_core.layout_file import NAME


def default_link_name(link_id: int) -> str:
    """The name of a link that has none: its ROS topic token."""
    return f'link_{link_id}'


@dataclass(frozen=True)
class RoadLink:
    """One directed road section, travelled from 0 to ``length``."""

    link_id: int  # unique over the network, >= 0
    name: str  # one ROS topic name token
    length: float  # [m], > 0
    lanes: int = 0  # lanes of the section, 0 = unknown
    shape: tuple[tuple[float, float], ...] = ()  # [m] centre line start -> end; () unknown

    def __post_init__(self) -> None:
        if isinstance(self.link_id, bool) or not isinstance(self.link_id, int | np.integer):
            raise ValueError(f'link id must be an integer, got {self.link_id!r}')
        if self.link_id < 0:
            raise ValueError(f'link id must be >= 0, got {self.link_id}')
        if not isinstance(self.name, str) or not NAME.match(self.name):
            raise ValueError(f'link {self.link_id}: name {self.name!r} is not a topic name token')
        if not (math.isfinite(self.length) and self.length > 0):
            raise ValueError(f'link {self.link_id}: length must be finite and > 0 m')
        if self.lanes < 0:
            raise ValueError(f'link {self.link_id}: lanes must be >= 0, got {self.lanes}')
        object.__setattr__(self, 'link_id', int(self.link_id))
        object.__setattr__(self, 'length', float(self.length))
        object.__setattr__(self, 'lanes', int(self.lanes))
        object.__setattr__(self, 'shape', _checked_shape(self.link_id, self.shape))

    def point_at(self, offset: float) -> tuple[float, float, float]:
        """(x [m], y [m], heading [rad] counter-clockwise from x) of the point ``offset`` [m]
        along the link (clamped to [0, length]); ValueError for a link without a shape."""
        if not self.shape:
            raise ValueError(f'link {self.link_id} has no shape')
        xy = np.asarray(self.shape, float)
        steps = np.hypot(*np.diff(xy, axis=0).T)
        along = np.concatenate(([0.0], np.cumsum(steps)))
        s = min(max(offset, 0.0), self.length) / self.length * along[-1]
        i = min(int(np.searchsorted(along, s, side='right')) - 1, len(steps) - 1)
        while steps[i] == 0.0 and i > 0:  # a repeated point: the heading of the step before
            i -= 1
        f = (s - along[i]) / steps[i] if steps[i] > 0 else 0.0
        (x0, y0), (x1, y1) = xy[i], xy[i + 1]
        x, y = x0 + f * (x1 - x0), y0 + f * (y1 - y0)
        return float(x), float(y), math.atan2(y1 - y0, x1 - x0)


def _checked_shape(link_id: int, shape) -> tuple[tuple[float, float], ...]:
    try:
        points = tuple((float(x), float(y)) for x, y in shape)
    except (TypeError, ValueError):
        raise ValueError(f'link {link_id}: shape must be a list of [x, y] points [m]') from None
    if not points:
        return ()
    if len(points) < 2 or not all(math.isfinite(c) for p in points for c in p):
        raise ValueError(f'link {link_id}: a shape needs at least 2 finite [x, y] points')
    if all(p == points[0] for p in points):
        raise ValueError(f'link {link_id}: the shape has no length (all its points are equal)')
    return points
