"""The graph's topic names and QoS profiles, defined once (see CONTRACT.md, Topics).

Every node, script and test takes its profiles from here. Data topics are reliable with
KEEP_ALL history on both ends: a reliable KEEP_LAST writer that outruns its reader drops
samples silently, KEEP_ALL makes the writer hold each sample until every matched reader
has acknowledged it, so nothing is lost. Latched topics (layout, episodes, scores) are
transient_local so that late joiners (a replayed bag, a recorder, a scorer started later)
still receive them.

Names are relative, so ``-r`` remaps and ``__ns`` namespaces apply; in the root namespace
they resolve to the contract's absolute names.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Topic names (relative; ``/road/...`` and ``/mlkm/...`` in the root namespace).
LAYOUT_TOPIC = 'road/sensor_layout'
EPISODE_TOPIC = 'road/episode'
GROUND_TRUTH_TOPIC = 'road/ground_truth'
DETECTIONS_PREFIX = 'road/sensors'
TRACKS_TOPIC = 'mlkm/tracks'
SCORE_TOPIC = 'mlkm/score'
DIAGNOSTICS_TOPIC = '/diagnostics'
MARKERS_TOPIC = 'mlkm/markers'
#: Absolute: the shards of one road share it whatever their namespaces.
HANDOFF_TOPIC = '/mlkm/handoff'
TF_STATIC_TOPIC = '/tf_static'
CLOCK_TOPIC = '/clock'

#: Topics a recording of the graph leaves out: ROS housekeeping (bag_recorder exclude_regex).
RECORD_EXCLUDE_REGEX = '^/(rosout|parameter_events)$'
#: Topics a replay plays (bag_player include_regex): the sensors' side of the graph only,
#: never the recorded tracks, scores or diagnostics, which the fresh nodes produce again.
REPLAY_INCLUDE_REGEX = r'^/road/(sensor_layout|episode|ground_truth|sensors/[^/]+/detections)$'

#: How many episodes (two EpisodeInfo messages each) and scores a late joiner still gets.
LATCHED_HISTORY_DEPTH = 1000


def detections_topic(sensor_name: str) -> str:
    """The detection topic of one sensor: ``road/sensors/<sensor_name>/detections``."""
    return f'{DETECTIONS_PREFIX}/{sensor_name}/detections'


def _keep_last(depth: int, durability: DurabilityPolicy) -> QoSProfile:
    """A reliable KEEP_LAST profile of ``depth`` messages."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=durability,
    )


#: /road/sensor_layout: reliable, transient_local, depth 1.
LAYOUT_QOS = _keep_last(1, DurabilityPolicy.TRANSIENT_LOCAL)

#: /road/episode: reliable, transient_local (the last LATCHED_HISTORY_DEPTH messages).
EPISODE_QOS = _keep_last(LATCHED_HISTORY_DEPTH, DurabilityPolicy.TRANSIENT_LOCAL)

#: Detections, ground truth and tracks: reliable, volatile, KEEP_ALL (nothing lost).
STREAM_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
DETECTIONS_QOS = STREAM_QOS
GROUND_TRUTH_QOS = STREAM_QOS
TRACKS_QOS = STREAM_QOS

#: /mlkm/score: reliable, transient_local (the last LATCHED_HISTORY_DEPTH episodes).
SCORE_QOS = _keep_last(LATCHED_HISTORY_DEPTH, DurabilityPolicy.TRANSIENT_LOCAL)

#: /diagnostics: reliable, volatile; periodic status, so a bounded history is enough.
DIAGNOSTICS_QOS = _keep_last(100, DurabilityPolicy.VOLATILE)

#: /clock: reliable writer, depth 1 (matches the usual best-effort clock readers too).
CLOCK_QOS = _keep_last(1, DurabilityPolicy.VOLATILE)

#: /mlkm/markers: reliable; transient_local depth 1, so a display that joins late gets the
#: latest picture at once (the node publishes only when it changed).
MARKERS_QOS = _keep_last(1, DurabilityPolicy.TRANSIENT_LOCAL)

#: /mlkm/handoff: reliable, transient_local, the last HANDOFF_HISTORY_DEPTH messages of each
#: shard: a shard that restarts takes up the offers it missed.
HANDOFF_HISTORY_DEPTH = 1000
HANDOFF_QOS = _keep_last(HANDOFF_HISTORY_DEPTH, DurabilityPolicy.TRANSIENT_LOCAL)
#: The hand-off's readers keep every message (KEEP_ALL): a KEEP_LAST reader whose executor
#: falls behind keeps only the newest ``depth`` and acknowledges the rest as delivered. The
#: writer publishes through ``mlkm_ros.publishing.ReliablePublisher`` with a flow-control
#: window of HANDOFF_FLOW_WINDOW (below the depth), so that it never overwrites a message a
#: reader has not acknowledged; a late joiner still gets the last HANDOFF_HISTORY_DEPTH.
HANDOFF_READER_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
HANDOFF_FLOW_WINDOW = HANDOFF_HISTORY_DEPTH // 2

#: /tf_static: reliable, transient_local, depth 1 (what tf2's static broadcasters offer).
TF_STATIC_QOS = _keep_last(1, DurabilityPolicy.TRANSIENT_LOCAL)
