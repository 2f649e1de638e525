"""The console scripts ``association_node`` and ``scorer_node`` (named by setup.py)."""

from mlkm_ros.lifecycle import entry_point

association_node = entry_point('mlkm_assoc.association_node')
scorer_node = entry_point('mlkm_assoc.scorer_node')
