"""Simulated road-side sensors, and the graph's shared QoS profiles and message conversions."""
