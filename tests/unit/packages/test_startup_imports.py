"""Nodes that associate nothing start without the association's heavy libraries.

scikit-learn, ``scipy.optimize`` and ``scipy.signal`` take 0.5-1.5 s of CPU each to import (a
few seconds on a busy machine), and the sources, the scorer and the merge never call them:
the associators import them where they are first used. The association node's solver and
tracker processes import them before the first detection (their warm-up and ``prestart``).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ('sklearn', 'scipy.optimize', 'scipy.signal')

# Runs in a fresh interpreter: imports the named module, reports which heavy ones got loaded.
PROBE = r"""
import importlib, json, sys
importlib.import_module(sys.argv[1])
print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] == 'sklearn'
                        or m in ('scipy.optimize', 'scipy.signal'))))
"""


def _heavy_after(module: str) -> list[str]:
    out = subprocess.run(
        [sys.executable, '-c', PROBE, module], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize(
    'module',
    [
        'road_sensors.sensor_sim',
        'road_sensors.log_source',
        'road_sensors.sumo_sensors',
        'mlkm_assoc.scorer_node',
        'mlkm_assoc.track_merge',
        'mlkm_core.associators',
        'mlkm_core.simulator',
        'mlkm_core.metrics',
    ],
)
def test_a_node_that_associates_nothing_imports_no_heavy_library(module) -> None:
    assert _heavy_after(module) == []


def test_the_probe_sees_a_heavy_import() -> None:
    assert 'scipy.optimize' in _heavy_after('scipy.optimize')
    assert 'sklearn' in _heavy_after('sklearn.cluster')
