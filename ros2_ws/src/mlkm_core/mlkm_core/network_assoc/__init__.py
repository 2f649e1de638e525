"""Association on a road network (``mlkm_core.network.RoadNetwork``): tracks across junctions.

A detection's ``sensor_index`` is the index of its station in the network's station arrays.
The methods, by name (``NETWORK_METHODS``):

* ``assignment``: one global matching of every detection to its successor over the hops of
  the network (``linking``), with the motion, the turn shares and the time lost at junctions
  fitted to the data being associated (``fit``);
* ``multiframe``, ``mlkm_robust``: the one-road tracking methods on each link, then one
  matching across the junctions under ``assignment``'s fitted model (``per_link``);
* ``gmlkm``: the baseline in the spirit of G-MLKM (the paper's MLKM on each link, then
  association across each junction with error correction by physical rules; ``gmlkm``, from
  our reading of the paper's follow-up, which the stronger methods must beat).

Every method returns one label per detection: a track id >= 0, or -1 (a detection left alone:
a false alarm, or a vehicle seen once).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc.fit import NetworkModel, calibrate_and_link
from mlkm_core.network_assoc.gmlkm import gmlkm_associate
from mlkm_core.network_assoc.hops import Hops, network_hops
from mlkm_core.network_assoc.per_link import per_link_associate
from mlkm_core.types import Detections

#: stations a track may pass unseen between two of its detections
MAX_SKIP = 2

__all__ = ['MAX_SKIP', 'NETWORK_METHODS', 'Hops', 'NetworkModel', 'associate_network']


def _assignment(net: RoadNetwork, d: Detections, seed: int) -> np.ndarray:
    labels, _ = calibrate_and_link(net, network_hops(net, MAX_SKIP), d)
    return labels


#: name -> (network, detections, seed) -> labels
NETWORK_METHODS: dict[str, Callable[[RoadNetwork, Detections, int], np.ndarray]] = {
    'assignment': _assignment,
    'gmlkm': lambda net, d, seed: gmlkm_associate(net, d, seed),
    **{
        name: lambda net, d, seed, name=name: per_link_associate(
            net, network_hops(net, MAX_SKIP), d, name, seed
        )
        for name in ('multiframe', 'mlkm_robust')
    },
}


def associate_network(
    net: RoadNetwork, d: Detections, method: str = 'assignment', seed: int = 0
) -> np.ndarray:
    """One label per detection of ``d`` (module docstring); ValueError for an unknown method
    or a detection at a station the network does not have."""
    if method not in NETWORK_METHODS:
        known = ', '.join(sorted(NETWORK_METHODS))
        raise ValueError(f'unknown network method {method!r}; choose from {known}')
    if len(d) and (d.sensor_index.min() < 0 or d.sensor_index.max() >= net.n_stations):
        raise ValueError(f'detections at station indexes outside [0, {net.n_stations})')
    if len(d) == 0:
        return np.zeros(0, np.int64)
    return NETWORK_METHODS[method](net, d, seed)
