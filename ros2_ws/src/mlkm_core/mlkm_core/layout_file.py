"""Road layout files (YAML): the stations of a real road, for a detection log or a live feed.

A traffic engineer with a detector log describes the road once::

    # stations in any order; ids are the sensor_id column of the detection log
    road_length_m: 510.0          # the road is [0, road_length_m] [m]
    stations:
      - {id: 0, name: loop_00, position_m: 50.0, lanes: 3}
      - {id: 1, name: loop_01, position_m: 150.0, lanes: 3}
    entries_m: []                 # on-ramp positions between stations [m]
    exits_m: []                   # off-ramp positions between stations [m]

``name`` (default ``sensor_<id>``) becomes the station's detection topic
``/road/sensors/<name>/detections``; ``lanes`` (default 0 = unknown) is the number of loops
the station has. Every problem is a :class:`LayoutFileError` that names the file and the
entry: a missing or non-numeric field, a duplicate id, name or position, a station off the
road, an unknown key (a typo must not pass silently).

A file with a top-level ``links:`` key is a road network instead (links, junctions, stations
on links): ``mlkm_core.network_file`` reads and writes that form, and its
``mlkm_core.network_file.read_network_file`` reads both forms.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from mlkm_core.types import Layout, default_sensor_name

TOP_KEYS = ('road_length_m', 'stations', 'entries_m', 'exits_m')
STATION_KEYS = ('id', 'name', 'position_m', 'lanes')
#: A station name is one ROS topic name token.
NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')


class LayoutFileError(ValueError):
    """A layout file that cannot be used; the message names the file and the entry."""


@dataclass(frozen=True)
class RoadLayout:
    """A layout with what the sensor layout message carries beside it."""

    layout: Layout
    lanes: np.ndarray = field(default=None)  # loops per station, 0 = unknown [lanes]
    entries: tuple[float, ...] = ()  # on-ramp positions [m]
    exits: tuple[float, ...] = ()  # off-ramp positions [m]

    def __post_init__(self) -> None:
        n = self.layout.n_sensors
        lanes = np.zeros(n, np.int64) if self.lanes is None else np.asarray(self.lanes, np.int64)
        if lanes.shape != (n,) or np.any(lanes < 0):
            raise ValueError('lanes: one count >= 0 per station')
        object.__setattr__(self, 'lanes', lanes)


def read_layout_file(path: str | Path) -> RoadLayout:
    """The road of ``path``; raises LayoutFileError (module docstring). A network file
    (``links:``) is refused here: ``mlkm_core.network_file.read_network_file`` reads both."""
    path = Path(path)
    doc = load_yaml(path)
    if isinstance(doc, dict) and 'links' in doc:
        raise LayoutFileError(
            f'{path}: a road network (links:), not a single road; read it as a network'
        )
    return road_from_mapping(doc, path)


def load_yaml(path: Path):
    """The YAML document of ``path``; LayoutFileError when it cannot be read or parsed."""
    try:
        return yaml.safe_load(path.read_text(encoding='utf-8'))
    except OSError as exc:
        raise LayoutFileError(f'{path}: {exc.strerror or exc}') from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise LayoutFileError(f'{path}: not YAML ({exc})') from None


def road_from_mapping(doc, path: Path) -> RoadLayout:
    """The single road of a YAML document read from ``path``."""
    if not isinstance(doc, dict):
        raise LayoutFileError(f'{path}: expected a mapping with {", ".join(TOP_KEYS)}')
    where = str(path)
    unknown_keys(doc, TOP_KEYS, where)
    road = _number(doc, 'road_length_m', where)
    stations = doc.get('stations')
    if not isinstance(stations, list) or not stations:
        raise LayoutFileError(f'{path}: stations: a non-empty list of stations is needed')
    rows = []
    for k, st in enumerate(stations):
        at = f'{path}: stations[{k}]'
        if not isinstance(st, dict):
            raise LayoutFileError(f'{at}: expected a mapping with {", ".join(STATION_KEYS)}')
        unknown_keys(st, STATION_KEYS, at)
        sid = st.get('id')
        if not isinstance(sid, int) or isinstance(sid, bool) or sid < 0:
            raise LayoutFileError(f'{at}: id must be an integer >= 0, got {sid!r}')
        name = st.get('name', default_sensor_name(sid))
        if not isinstance(name, str) or not NAME.match(name):
            raise LayoutFileError(
                f'{at}: name {name!r} is not a topic name token (a letter, then letters, '
                'digits or _)'
            )
        lanes = st.get('lanes', 0)
        if not isinstance(lanes, int) or isinstance(lanes, bool) or lanes < 0:
            raise LayoutFileError(f'{at}: lanes must be an integer >= 0, got {lanes!r}')
        x = _number(st, 'position_m', at)
        if not 0.0 <= x <= road:
            raise LayoutFileError(f'{at}: position_m {x:g} is off the road [0, {road:g}] m')
        rows.append((x, sid, name, lanes))
    rows.sort()
    for (xa, ia, *_), (xb, ib, *_) in zip(rows, rows[1:], strict=False):
        if xa == xb:
            raise LayoutFileError(f'{path}: stations {ia} and {ib} share position_m {xa:g}')
    for what, values in (('id', [r[1] for r in rows]), ('name', [r[2] for r in rows])):
        seen = {v for v in values if values.count(v) > 1}
        if seen:
            raise LayoutFileError(f'{path}: {what} {sorted(seen)[0]!r} is used twice')
    ramps = []
    for key in ('entries_m', 'exits_m'):
        values = doc.get(key) or []
        if not isinstance(values, list):
            raise LayoutFileError(f'{path}: {key}: a list of positions [m] is needed')
        for v in values:
            if not finite(v) or not 0.0 <= v <= road:
                raise LayoutFileError(f'{path}: {key}: {v!r} is not a position on the road')
        ramps.append(tuple(float(v) for v in values))
    layout = Layout(
        road,
        np.array([r[0] for r in rows]),
        np.array([r[1] for r in rows], np.int64),
        tuple(r[2] for r in rows),
    )
    return RoadLayout(layout, np.array([r[3] for r in rows], np.int64), *ramps)


def write_layout_file(path: str | Path, road: RoadLayout, comment: str = '') -> None:
    """Write ``road`` in the format :func:`read_layout_file` reads; ``comment`` (one or more
    lines) heads the file. A station name the reader would refuse raises LayoutFileError."""
    lay = road.layout
    bad = [n for n in lay.names if not NAME.match(n)]
    if bad:
        raise LayoutFileError(f'{path}: station name {bad[0]!r} is not a topic name token')
    lines = [f'# {c}' for c in comment.splitlines()] if comment else []
    lines.append(f'road_length_m: {float(lay.road_length)!r}')
    lines.append('stations:')
    for sid, name, x, n in zip(lay.sensor_ids, lay.names, lay.positions, road.lanes):
        lines.append(
            f'  - {{id: {int(sid)}, name: {scalar(name)}, position_m: {float(x)!r}, '
            f'lanes: {int(n)}}}'
        )
    for key, values in (('entries_m', road.entries), ('exits_m', road.exits)):
        lines.append(f'{key}: [{", ".join(repr(float(v)) for v in values)}]')
    Path(path).write_text('\n'.join(lines) + '\n', encoding='utf-8')


def scalar(name: str) -> str:
    """``name`` as YAML reads it back: quoted where YAML would take it for another type
    (``on``, ``no``, ``null``, ...)."""
    return name if yaml.safe_load(name) == name else f"'{name}'"


def unknown_keys(doc: dict, known: tuple[str, ...], where: str) -> None:
    """LayoutFileError naming the first key of ``doc`` that is not one of ``known``."""
    extra = [k for k in doc if k not in known]
    if extra:
        raise LayoutFileError(f'{where}: unknown key {extra[0]!r} (known: {", ".join(known)})')


def finite(v) -> bool:
    """Whether ``v`` is a finite int or float (not a bool) as YAML gives numbers."""
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _number(doc: dict, key: str, where: str) -> float:
    v = doc.get(key)
    if not finite(v):
        raise LayoutFileError(f'{where}: {key} must be a finite number, got {v!r}')
    if key == 'road_length_m' and not v > 0:
        raise LayoutFileError(f'{where}: road_length_m must be > 0, got {v!r}')
    return float(v)
