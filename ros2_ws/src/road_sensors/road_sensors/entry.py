"""Entry points of the installed node executables: SIGINT and SIGTERM are caught before the
node's module (rclpy, numpy, ...) is imported, so a Ctrl-C at any moment of the start-up ends
the process with exit 0 and no traceback (mlkm_ros.lifecycle)."""

from mlkm_ros.lifecycle import run


def sensor_sim() -> int:
    return run('road_sensors.sensor_sim')


def sumo_sensors() -> int:
    return run('road_sensors.sumo_sensors')
