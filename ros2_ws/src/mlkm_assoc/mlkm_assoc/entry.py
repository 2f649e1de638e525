"""The console scripts ``association_node``, ``scorer_node`` and ``track_merge`` (named by
setup.cfg)."""

from mlkm_ros.lifecycle import entry_point

association_node = entry_point('mlkm_assoc.association_node')
scorer_node = entry_point('mlkm_assoc.scorer_node')
track_merge = entry_point('mlkm_assoc.track_merge')
