"""Make ``mlkm_core`` and ``mlkm_sumo`` importable from the source tree when not installed."""

import importlib.util
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[2] / 'ros2_ws' / 'src'
for _pkg in ('mlkm_core', 'mlkm_sumo'):
    if importlib.util.find_spec(_pkg) is None:
        sys.path.insert(0, str(SRC / _pkg))
