"""The installed config/*.param.yaml files hold exactly the defaults the nodes declare."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml
from ament_index_python.packages import get_package_share_directory

from mlkm_assoc import association_node, scorer_node, track_merge
from road_sensors import log_params, sensor_sim, sumo_params
from rosbag_mcap import settings


@pytest.mark.parametrize(
    'package,node,specs',
    [
        ('road_sensors', 'sensor_sim', sensor_sim._sim_specs() + sensor_sim._NODE_SPECS),
        ('road_sensors', 'log_source', log_params.SPECS),
        ('mlkm_assoc', 'association_node', association_node.SPECS),
        ('mlkm_assoc', 'scorer_node', scorer_node.SPECS),
        ('mlkm_assoc', 'track_merge', track_merge.SPECS),
    ],
)
def test_param_file_matches_declared_defaults(package, node, specs) -> None:
    path = Path(get_package_share_directory(package)) / 'config' / f'{node}.param.yaml'
    params = yaml.safe_load(path.read_text())['/**']['ros__parameters']
    declared = {s.name: s.default for s in specs}
    assert params == declared, f'update {path.name} to the declared defaults'
    assert all(type(params[k]) is type(v) for k, v in declared.items())
    for spec in specs:
        assert '[' in spec.description, f'{spec.name}: description without a unit'


#: Every node of the product and the table its parameters are declared from.
ALL_NODES = [
    ('sensor_sim', sensor_sim._sim_specs() + sensor_sim._NODE_SPECS),
    ('sumo_sensors', sumo_params.SPECS),
    ('log_source', log_params.SPECS),
    ('association_node', association_node.SPECS),
    ('scorer_node', scorer_node.SPECS),
    ('track_merge', track_merge.SPECS),
    ('bag_recorder', settings.RECORDER_PARAMS),
    ('bag_player', settings.PLAYER_PARAMS),
]


@pytest.mark.parametrize('node,specs', ALL_NODES, ids=[n for n, _ in ALL_NODES])
def test_every_parameter_is_described_and_every_number_has_a_unit(node, specs) -> None:
    """What `ros2 param describe` shows (tests/graph/test_launch_files.py checks it live):
    a description for every parameter, and for every number its unit in brackets."""
    bad = []
    for spec in specs:
        number = isinstance(spec.default, int | float) and not isinstance(spec.default, bool)
        if not spec.description.strip():
            bad.append(f'{spec.name}: no description')
        elif number and not re.search(r'\[[^\]]+\]', spec.description):
            bad.append(f'{spec.name}: a number without a unit: {spec.description!r}')
    assert not bad, f'{node}:\n' + '\n'.join(bad)
