"""Record and replay rosbag2-compatible MCAP bags; storage.py and definitions.py are ROS-free."""
