"""Eclipse SUMO as a ROS-free source of road-sensor datasets.

Scenarios (``SCENARIOS``) are built from plain-text SUMO sources by netconvert into a cache;
sensor stations carry one loop detector per lane; a measurement model adds noise, misses and
false alarms. Entry points: ``generate`` (a batch), ``episodes`` (batches of N vehicles that
all leave the road), ``PassageStream`` (time-ordered passages for a live source), ``road``
(the stations of a seed, without running SUMO) and ``mlkm_sumo.cli.main`` (``mlkm sumo``);
road networks with junctions: ``road_networks`` (``draw_network``, ``generate_network``).
"""

from .api import Passage, PassageStream, SumoDataset, episodes, generate, road
from .measurement import KIND_NAMES, MeasurementConfig
from .network import SumoError
from .scenarios import SCENARIOS, Road, make_road

__all__ = [
    'KIND_NAMES',
    'SCENARIOS',
    'MeasurementConfig',
    'Passage',
    'PassageStream',
    'Road',
    'SumoDataset',
    'SumoError',
    'episodes',
    'generate',
    'make_road',
    'road',
]
