"""mlkm_sumo stays ROS-free (like mlkm_core): no source line imports rclpy or messages."""

import ast
from pathlib import Path

SUMO_SRC = Path(__file__).resolve().parents[3] / 'ros2_ws' / 'src' / 'mlkm_sumo' / 'mlkm_sumo'


def imported_modules(path: Path) -> list[str]:
    names = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.append(node.module)
    return names


def is_ros(module: str) -> bool:
    top = module.split('.')[0]
    return top.startswith(('rclpy', 'rcl', 'rosidl')) or top.endswith(('_msgs', '_interfaces'))


def test_mlkm_sumo_imports_no_ros():
    files = sorted(SUMO_SRC.rglob('*.py'))
    assert len(files) >= 6
    offenders = {f.name: m for f in files if (m := [x for x in imported_modules(f) if is_ros(x)])}
    assert not offenders, offenders
    assert is_ros('rclpy.node') and is_ros('road_sensor_msgs.msg') and not is_ros('libsumo')
