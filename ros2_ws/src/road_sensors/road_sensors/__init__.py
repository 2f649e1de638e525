"""Simulated road-side sensors: the sensor_sim node."""
