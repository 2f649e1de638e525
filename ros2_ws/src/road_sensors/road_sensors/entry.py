"""The console scripts ``sensor_sim`` and ``sumo_sensors`` (named by setup.py)."""

from mlkm_ros.lifecycle import entry_point

sensor_sim = entry_point('road_sensors.sensor_sim')
sumo_sensors = entry_point('road_sensors.sumo_sensors')
