"""The core (``mlkm_core``) stays ROS-free: no rclpy, no message packages.

Two checks: importing every module of the package in a fresh interpreter loads neither rclpy
nor any ``*_msgs`` / ``*_interfaces`` module, and no source line imports them (which also
catches imports inside functions that the first check would not execute).
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

CORE_SRC = Path(__file__).resolve().parents[3] / 'ros2_ws' / 'src' / 'mlkm_core' / 'mlkm_core'

# Runs in a fresh interpreter: imports every module of mlkm_core, reports what got loaded.
PROBE = r"""
import importlib, json, pkgutil, sys
sys.path.insert(0, sys.argv[1])
import mlkm_core
assert mlkm_core.__file__.startswith(sys.argv[1]), mlkm_core.__file__
names = ['mlkm_core'] + [m.name for m in pkgutil.walk_packages(mlkm_core.__path__, 'mlkm_core.')]
for name in names:
    importlib.import_module(name)
print(json.dumps({'modules': names, 'loaded': sorted(sys.modules)}))
"""


def is_ros(module: str) -> bool:
    top = module.split('.')[0]
    return (
        top in {'rclpy', 'rosidl_runtime_py', 'rosidl_parser', 'builtin_interfaces'}
        or top.endswith('_msgs')
        or top.endswith('_interfaces')
        or top.startswith('rcl')
    )


def test_is_ros_recognises_ros_modules():
    assert is_ros('rclpy.node') and is_ros('road_sensor_msgs.msg') and is_ros('std_msgs')
    assert is_ros('diagnostic_msgs.msg') and is_ros('builtin_interfaces.msg')
    assert not is_ros('numpy') and not is_ros('mlkm_core.types') and not is_ros('sklearn')


def test_importing_every_core_module_loads_no_ros():
    out = subprocess.run(
        [sys.executable, '-c', PROBE, str(CORE_SRC.parent)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, f'importing the core failed:\n{out.stderr[-3000:]}'
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert 'mlkm_core.types' in report['modules'], report['modules']
    assert 'mlkm_core.associators.base' in report['modules'], report['modules']
    ros = [m for m in report['loaded'] if is_ros(m)]
    assert not ros, f'importing mlkm_core loaded ROS modules: {ros}'


def ros_imports(source: str, filename: str) -> list[str]:
    """``import``/``from`` statements of ``source`` naming a ROS module, as 'line: module'."""
    found = []
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found += [f'{node.lineno}: {n}' for n in names if is_ros(n)]
    if 'importlib' in source:  # dynamic imports of ROS modules by name
        for node in ast.walk(ast.parse(source, filename)):
            if (
                isinstance(node, ast.Constant)
                and isinstance(node.value, str)
                and is_ros(node.value)
                and node.value.replace('.', '').isidentifier()
            ):
                found.append(f'{node.lineno}: {node.value!r}')
    return found


def test_scanner_finds_ros_imports():
    src = 'import os\nimport rclpy.node\ndef f():\n    from road_sensor_msgs.msg import Track\n'
    assert ros_imports(src, 'x.py') == ['2: rclpy.node', '4: road_sensor_msgs.msg']


def test_core_source_has_no_ros_import():
    files = sorted(CORE_SRC.rglob('*.py'))
    assert files, CORE_SRC
    offenders = {
        str(f.relative_to(CORE_SRC)): hits
        for f in files
        if (hits := ros_imports(f.read_text(), str(f)))
    }
    assert not offenders, f'mlkm_core imports ROS: {offenders}'
