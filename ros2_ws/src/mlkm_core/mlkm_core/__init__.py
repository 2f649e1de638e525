"""ROS-free core of the MLKM product: simulator, associators, metrics. Imports no rclpy."""
