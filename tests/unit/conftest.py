"""The unit tier (tests/unit/<package>/): tests that start no node and no DDS graph.

The ROS-free packages (``mlkm_core``, ``mlkm_sumo``) and ``rosbag_mcap``'s storage are
importable from the source tree when they are not installed, so that their tests run without
``make setup``. The shared fixtures are in tests/conftest.py.
"""

import importlib.util
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[2] / 'ros2_ws' / 'src'
for _pkg in ('mlkm_core', 'mlkm_sumo', 'rosbag_mcap'):
    if importlib.util.find_spec(_pkg) is None:
        sys.path.insert(0, str(SRC / _pkg))
