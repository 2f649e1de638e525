"""ROS glue shared by the nodes: QoS profiles, message conversions, parameter helpers."""
