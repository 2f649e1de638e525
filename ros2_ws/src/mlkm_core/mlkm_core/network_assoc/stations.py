"""The stations of a road network in the shape the live graph handles stations, and the
associator that works on them.

The nodes buffer, validate and publish detections per station: a station's id, its name (its
detection topic) and the position a detection of it carries. On one road that is a
:class:`~mlkm_core.types.Layout`. :class:`NetworkStations` is the same for the stations of a
:class:`~mlkm_core.network.RoadNetwork`: each position is along the station's own link [m], so
positions neither increase nor share one road, and the network itself travels along. Code that
needs the road (the single-road associators, the road's markers) is never handed one:
:func:`associator_for` picks the network associator for it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mlkm_core.associators.base import Associator, AssociatorConfig, make_associator
from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc import NETWORK_METHODS, associate_network
from mlkm_core.types import Detections, Layout


@dataclass(frozen=True)
class NetworkStations(Layout):
    """The stations of ``network`` as a Layout (module docstring). ``road_length`` is the
    longest link's length [m]; a station's position is its offset along its link [m]."""

    network: RoadNetwork = field(default=None)

    def _check_positions(self, pos: np.ndarray) -> None:
        if not isinstance(self.network, RoadNetwork):
            raise ValueError('NetworkStations needs its RoadNetwork')
        if pos.size != self.network.n_stations or np.any(pos < 0):
            raise ValueError('one position along its link per station of the network')


def network_stations(net: RoadNetwork) -> NetworkStations:
    """The stations of ``net`` in its own order: index i is ``net``'s station i."""
    return NetworkStations(
        road_length=max(k.length for k in net.links),
        positions=np.asarray(net.station_offsets, float),
        sensor_ids=np.asarray(net.station_ids, np.int64),
        names=tuple(net.station_names),
        network=net,
    )


def network_method_problem(method: str) -> str | None:
    """Why ``method`` cannot associate a road network, or None when it can."""
    if method in NETWORK_METHODS:
        return None
    known = ', '.join(sorted(NETWORK_METHODS))
    return f'method {method!r} does not associate road networks; the network methods: {known}'


class NetworkAssociator(Associator):
    """A network method (``NETWORK_METHODS``) behind the Associator interface, so that the
    live graph's incremental sessions drive it as they drive a single road's method: each
    segment fed re-associates everything fed so far (exact: incremental equals batch)."""

    name = 'network'

    def __init__(self, method: str, config: AssociatorConfig | None = None) -> None:
        problem = network_method_problem(method)
        if problem:
            raise ValueError(problem)
        super().__init__(config)
        self.method = method

    def associate(self, layout: Layout, detections: Detections, n_targets: int) -> np.ndarray:
        if not isinstance(layout, NetworkStations):
            raise TypeError('a network method needs the stations of a road network')
        return associate_network(layout.network, detections, self.method, self.config.seed)


def associator_for(layout: Layout, method: str, config: AssociatorConfig) -> Associator:
    """The associator ``method`` for ``layout``: the network method on the stations of a road
    network, the registered single-road method otherwise. ValueError for a method that does
    not work there."""
    if isinstance(layout, NetworkStations):
        return NetworkAssociator(method, config)
    return make_associator(method, config)
