"""The console scripts ``bag_recorder`` and ``bag_player`` (named by setup.py)."""

from mlkm_ros.lifecycle import entry_point

bag_recorder = entry_point('rosbag_mcap.recorder')
bag_player = entry_point('rosbag_mcap.player')
