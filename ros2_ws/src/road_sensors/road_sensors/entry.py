"""The console scripts ``sensor_sim``, ``sumo_sensors`` and ``log_source`` (named by
setup.cfg)."""

from mlkm_ros.lifecycle import entry_point

sensor_sim = entry_point('road_sensors.sensor_sim')
sumo_sensors = entry_point('road_sensors.sumo_sensors')
log_source = entry_point('road_sensors.log_source')
