#!/usr/bin/env python3
"""Point the ROS 2 wheels' exported CMake files at this interpreter's include directories.

The ROS 2 Jazzy PyPI wheels were built in a manylinux container; their exported CMake targets
(``share/<pkg>/cmake/*Export*.cmake``, e.g. ``std_msgs::std_msgs__rosidl_generator_py``) name
that builder's Python include directory (``/opt/python/cp312-cp312/include/python3.12``) and
its numpy include directory. An interface package that depends on them (our
``road_sensor_msgs``) then fails to configure, because CMake refuses imported targets whose
include directories do not exist.

This script rewrites every such entry to the directories of the Python that runs it (run it
with the venv's interpreter): ``sysconfig``'s include directory and ``numpy.get_include()``.
It touches only entries that differ from those, so a second run changes nothing.

Usage: ``.venv/bin/python scripts/fix_cmake_paths.py [PREFIX]`` (PREFIX defaults to
``sys.prefix``). Prints how many files it changed.
"""

from __future__ import annotations

import re
import sys
import sysconfig
from pathlib import Path

import numpy

PY_TAG = f'python{sys.version_info.major}.{sys.version_info.minor}'
# One absolute path in a quoted CMake list (entries are separated by ';').
_ENTRY = r'(?<=[";])/[^";\s]*'
PY_INCLUDE_RE = re.compile(rf'{_ENTRY}/include/{PY_TAG}(?=[";])')
NUMPY_INCLUDE_RE = re.compile(rf'{_ENTRY}/site-packages/numpy/(?:_core|core)/include(?=[";])')


def fix_text(text: str, py_include: str, np_include: str) -> str:
    """Return ``text`` with foreign Python/numpy include directories replaced."""
    text = PY_INCLUDE_RE.sub(lambda m: py_include, text)
    return NUMPY_INCLUDE_RE.sub(lambda m: np_include, text)


def cmake_files(prefix: Path):
    """The CMake files the wheels install under ``prefix``."""
    for pattern in ('share/*/cmake/*.cmake', 'lib/cmake/*/*.cmake'):
        yield from sorted(prefix.glob(pattern))


def main(argv: list[str]) -> int:
    prefix = Path(argv[1] if len(argv) > 1 else sys.prefix).resolve()
    py_include = sysconfig.get_paths()['include']
    np_include = numpy.get_include()
    for needed in (py_include, np_include):
        if not Path(needed).is_dir():
            print(f'fix_cmake_paths: include directory {needed} does not exist', file=sys.stderr)
            return 1
    changed = 0
    for path in cmake_files(prefix):
        try:
            text = path.read_text()
        except (UnicodeDecodeError, OSError):
            continue
        if PY_TAG not in text and 'numpy' not in text:
            continue
        new = fix_text(text, py_include, np_include)
        if new != text:
            path.write_text(new)
            changed += 1
    print(
        f'fix_cmake_paths: {changed} file(s) updated under {prefix} '
        f'(python include {py_include}, numpy include {np_include})'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv))
