"""The installed config/*.param.yaml files hold exactly the defaults the nodes declare."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from ament_index_python.packages import get_package_share_directory

from mlkm_assoc import association_node, scorer_node
from road_sensors import log_params, sensor_sim


@pytest.mark.parametrize(
    'package,node,specs',
    [
        ('road_sensors', 'sensor_sim', sensor_sim._sim_specs() + sensor_sim._NODE_SPECS),
        ('road_sensors', 'log_source', log_params.SPECS),
        ('mlkm_assoc', 'association_node', association_node.SPECS),
        ('mlkm_assoc', 'scorer_node', scorer_node.SPECS),
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
