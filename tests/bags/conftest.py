"""Helpers for the bag tests: import path fallback, private DDS domains, process cleanup."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PKG_SRC = REPO / 'ros2_ws' / 'src' / 'rosbag_mcap'

if importlib.util.find_spec('rosbag_mcap') is None:  # not installed: use the source tree
    sys.path.insert(0, str(PKG_SRC))
