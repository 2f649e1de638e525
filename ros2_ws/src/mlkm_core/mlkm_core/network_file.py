"""Road network files (YAML): the network form of the layout file, beside the single road.

A file whose top level has ``links:`` describes a road network (``mlkm_core.network``)::

    # a road network: directed links joined at junctions, stations on links
    links:                       # id, name (topic token, default link_<id>), length [m], lanes
      - {id: 0, name: main_in, length_m: 800.0, lanes: 3,
         shape_m: [[0, 0], [800, 0]]}  # optional: its centre line, x east, y north [m]
      - {id: 1, name: main_out, length_m: 900.0, lanes: 3}
      - {id: 2, name: exit_ramp, length_m: 300.0, lanes: 1}
    connections:                 # a vehicle at the end of `from` can continue on `to`
      - {from: 0, to: 1}
      - {from: 0, to: 2}
    entries:                     # a link start (position_m 0, the default) or a point inside
      - {link: 0}
    exits:                       # a link end (default position_m = its length) or inside
      - {link: 1}
      - {link: 2}
    stations:                    # ids unique over the network (the detection log's sensor_id)
      - {id: 0, name: loop_00, link: 0, position_m: 200.0, lanes: 3}  # along its link [m]
      - {id: 1, name: loop_01, link: 1, position_m: 500.0, lanes: 3}
      - {id: 2, name: loop_02, link: 2, position_m: 150.0, lanes: 1}

``connections``, ``entries`` and ``exits`` may be left out: a link nothing leads into and
without an entry is entered at its start, a link nothing leaves and without an exit is left at
its end. Any other file is the single-road form of ``mlkm_core.layout_file``; read here it
becomes the one-link network of :meth:`RoadNetwork.single_road`. Every problem is a
LayoutFileError naming the file and the entry; unknown keys are errors.
"""

from __future__ import annotations

from pathlib import Path

from mlkm_core.layout_file import LayoutFileError, load_yaml, road_from_mapping, scalar
from mlkm_core.network import RoadNetwork, network_from_mapping, network_to_mapping


def is_network_file(path: str | Path) -> bool:
    """Whether ``path`` holds the network form (a top-level ``links:``); False also for a file
    that cannot be read (reading it in either form then says why)."""
    try:
        doc = load_yaml(Path(path))
    except LayoutFileError:  # the reader of either form reports it
        return False
    return isinstance(doc, dict) and 'links' in doc


def read_network_file(path: str | Path) -> RoadNetwork:
    """The network of ``path``, either form (module docstring); raises LayoutFileError."""
    path = Path(path)
    doc = load_yaml(path)
    if isinstance(doc, dict) and 'links' in doc:
        return network_from_mapping(doc, str(path))
    return RoadNetwork.single_road(road_from_mapping(doc, path))


def write_network_file(path: str | Path, net: RoadNetwork, comment: str = '') -> None:
    """Write ``net`` in the network form :func:`read_network_file` reads back to an equal
    network (a single road too); ``comment`` (one or more lines) heads the file."""
    data = network_to_mapping(net)
    lines = [f'# {c}' for c in comment.splitlines()] if comment else []
    for key, values in data.items():
        if not values:
            lines.append(f'{key}: []')
            continue
        lines.append(f'{key}:')
        lines += [f'  - {{{", ".join(_item(k, v) for k, v in d.items())}}}' for d in values]
    Path(path).write_text('\n'.join(lines) + '\n', encoding='utf-8')


def _item(key: str, value) -> str:
    if isinstance(value, str):
        return f'{key}: {scalar(value)}'
    return f'{key}: {value!r}'
