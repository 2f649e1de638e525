"""The replay graph: a recorded bag played into fresh association and scoring nodes.

    ros2 launch road_sensors replay.launch.py bag:=bags/sample [method:=mlkm] [rate:=0.0]

The graph of ``make replay``: ``bag_player`` plays the bag's layout, episode, sensor and
ground-truth topics (never its recorded tracks, scores or diagnostics) -> ``association_node``
-> ``scorer_node`` (accuracy on /mlkm/score, in its log). Both nodes follow the input
(``mode:=auto``): a bag of episodes is scored per episode, a bag of an open road (no
/road/episode in it) per ``window`` of stamp time, with links committed ``lag`` seconds later.
Each node reads its ``config/<node>.param.yaml`` and then the arguments below. The player waits
until the association node and the scorer subscribed, plays, and stays up (so that both keep
the latched layout and episodes); Ctrl-C ends the graph.
``ros2 launch road_sensors replay.launch.py -s`` lists the arguments.
"""

from pathlib import Path

from mlkm_ros.qos import REPLAY_INCLUDE_REGEX
from road_sensors.launch_graph import association_node, description, node

ARGUMENTS = (
    ('bag', '', 'bag directory (or a lone .mcap file) to replay; required [-]'),
    ('rate', '0.0', 'playback speed factor; 1.0 = recorded timing, 0 = as fast as taken [-]'),
    ('method', 'mlkm', 'associator of association_node in episodes mode [-]'),
    ('mode', 'auto', 'association and scoring: auto (follow the bag), episodes or stream [-]'),
    ('stream_method', 'multiframe', 'associator of association_node in stream mode [-]'),
    ('lag', '15.0', 'stream: links revisable until the newest stamp is this far past [s]'),
    ('quiet_flush', '0.0', 'stream: flush a road quiet for this long (wall time); 0 = lag [s]'),
    ('window', '60.0', 'stream: scoring window of stamp time [s]'),
)


def nodes(context):
    arg = context.launch_configurations
    if not arg['bag']:
        raise ValueError('replay.launch.py needs bag:=<bag directory or .mcap file>')
    bag = Path(arg['bag']).expanduser().resolve()
    if not bag.exists():
        raise ValueError(f'bag:={arg["bag"]}: {bag} does not exist')
    player = {
        'bag': str(bag),
        'rate': float(arg['rate']),
        'include_regex': REPLAY_INCLUDE_REGEX,
        # the association node on every sensor topic, the scorer on the truth; no time limit:
        # never play to nobody
        'wait_for_subscribers': 1,
        'wait_timeout': 0.0,
        'linger': -1.0,
    }
    return [
        # its tracks wait for the scorer and the user's own subscribers
        association_node(
            arg,
            1,
            {
                'mode': arg['mode'],
                'method': arg['method'],
                'stream_method': arg['stream_method'],
                'lag': float(arg['lag']),
                'quiet_flush': float(arg['quiet_flush']),
            },
        ),
        node(
            arg, 'mlkm_assoc', 'scorer_node', {'mode': arg['mode'], 'window': float(arg['window'])}
        ),
        node(arg, 'rosbag_mcap', 'bag_player', player),
    ]


def generate_launch_description():
    return description(ARGUMENTS, nodes)
