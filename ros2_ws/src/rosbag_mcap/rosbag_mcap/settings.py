"""The parameters of ``bag_recorder`` and ``bag_player``: one table each, read once at
start-up (``mlkm_ros.params.declare_startup``). config/bag_recorder.param.yaml and
config/bag_player.param.yaml list the same defaults for users.
"""

from __future__ import annotations

from mlkm_ros.params import StartupParam
from rosbag_mcap.storage import DEFAULT_CHUNK_SIZE

RECORDER_PARAMS = (
    StartupParam(
        'output',
        '',
        'Bag directory to create (must not exist or be empty); '
        'empty: bags/rosbag2_<local time> under the working directory.',
    ),
    StartupParam('topics', (), 'Topics to record; empty (and no include_regex): all topics.'),
    StartupParam(
        'include_regex', '', 'Also record topics whose name matches this Python regex (re.search).'
    ),
    StartupParam(
        'exclude_regex',
        '',
        'Never record topics whose name matches this Python regex (re.search).',
    ),
    StartupParam(
        'include_hidden_topics',
        False,
        "Record hidden topics (a name token starting with '_') when recording all.",
    ),
    StartupParam(
        'discovery_period', 0.5, 'Period of the graph poll that finds new topics [s].', 0.05, 60.0
    ),
    StartupParam(
        'flush_period',
        1.0,
        'Period of closing the current MCAP chunk, so that a recording killed without '
        'a clean stop keeps what was flushed [s]; 0 = only at the end.',
        0.0,
        3600.0,
    ),
    StartupParam(
        'max_duration',
        0.0,
        'Stop recording after this long [s]; 0 = until SIGINT or SIGTERM.',
        0.0,
        1e9,
    ),
    StartupParam(
        'stop_drain_timeout',
        30.0,
        'On stop, keep taking the messages already delivered until none arrives for '
        'stop_idle seconds, but at most this long [s]; a second SIGINT/SIGTERM cuts it '
        'short.',
        0.0,
        3600.0,
    ),
    StartupParam(
        'stop_idle',
        0.5,
        'On stop, the drain ends after this long without a new message [s].',
        0.01,
        60.0,
    ),
    StartupParam('compression', 'zstd', 'MCAP chunk compression: zstd, lz4 or none.'),
    StartupParam(
        'chunk_size',
        DEFAULT_CHUNK_SIZE,
        'MCAP chunk size before compression [byte].',
        1024,
        1 << 30,
        integer=True,
    ),
)

PLAYER_PARAMS = (
    StartupParam('bag', '', 'Bag directory or .mcap file to play (required).'),
    StartupParam(
        'rate',
        1.0,
        'Playback speed factor [-]: 1.0 = recorded timing, 2.0 = twice as fast; 0 = as fast '
        'as the middleware takes the messages (keep_all: blocks, never drops).',
        0.0,
        1000.0,
    ),
    StartupParam('loop', False, 'Play the bag again and again.'),
    StartupParam('start_offset', 0.0, 'Skip this much of the bag from its start [s].', 0.0, 1e9),
    StartupParam('topics', (), 'Topics to play; empty: all (see regexes).'),
    StartupParam('include_regex', '', 'Also play topics matching this Python regex (re.search).'),
    StartupParam('exclude_regex', '', 'Never play topics matching this Python regex (re.search).'),
    StartupParam(
        'remap',
        (),
        "Topic renames 'from:=to' applied to recorded names "
        '(ROS remapping -r from:=to works as well).',
    ),
    StartupParam('publish_clock', False, 'Publish the bag time on /clock while playing.'),
    StartupParam('clock_rate', 40.0, 'How often /clock is published [Hz].', 0.1, 1000.0),
    StartupParam(
        'wait_for_subscribers',
        0,
        'Before playing, wait until every played volatile topic has at least this many '
        'matched subscriptions (or wait_timeout passes) [-].',
        0,
        1000,
        integer=True,
    ),
    StartupParam(
        'wait_timeout',
        30.0,
        'Longest wait for subscribers before playing anyway [s]; 0 = no limit (wait '
        'until they match or the player is stopped).',
        0.0,
        1e6,
    ),
    StartupParam(
        'linger',
        0.0,
        'Stay up this long after the last message, so that late subscribers still get '
        'the latched (transient_local) topics [s]; -1 = until interrupted.',
        -1.0,
        1e9,
    ),
)
