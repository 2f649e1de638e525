"""Detections CSV files on a road network: each row's station found by its ``sensor_id`` in
the network layout (``mlkm_core.network``), its ``position_m`` checked against the station's
position along its link. Used by ``csvio.read_detections(..., network=...)``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mlkm_core.network import RoadNetwork

#: A row's position may differ from the layout's by this much (the CSV's usual three
#: decimals) [m].
POSITION_TOLERANCE = 1e-3


def position_problem(
    path: Path, net: RoadNetwork, position_of: dict[int, tuple[float, int]]
) -> str | None:
    """Why the rows do not fit ``net``, naming the line: a sensor id that is not a station of
    it, or a position_m that is not the station's (``position_of``: sensor id -> (position,
    first line)); None when they fit."""
    index = {int(s): k for k, s in enumerate(net.station_ids)}
    for sid, (pos, line) in sorted(position_of.items(), key=lambda kv: kv[1][1]):
        k = index.get(sid)
        if k is None:
            return f'{path}: line {line}: sensor {sid} is not a station of the network'
        at = float(net.station_offsets[k])
        if abs(pos - at) > POSITION_TOLERANCE:
            return (
                f'{path}: line {line}: sensor {sid} at position_m {pos}, but the network puts '
                f'it at {at:g} m along link {int(net.station_links[k])}'
            )
    return None


def station_indexes(net: RoadNetwork, ids: np.ndarray) -> np.ndarray:
    """The station index of each sensor id (every id is a station of ``net``)."""
    by_id = np.argsort(net.station_ids)
    return by_id[np.searchsorted(net.station_ids[by_id], ids)]
