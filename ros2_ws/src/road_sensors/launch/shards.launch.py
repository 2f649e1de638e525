"""A long road split over several association nodes (shards) with track hand-off.

    ros2 launch road_sensors shards.launch.py [shards:=4] [stations:=40] [duration:=300.0]

The graph of ``make demo-shards``: ``sumo_sensors`` in continuous mode on the 5 km SUMO
highway -> ``shards`` ``association_node`` instances in stream mode, shard k in namespace
``/shard_k`` owning the k-th run of stations (``shard_index``, ``shard_count``; the road's
topics from ``source_namespace:=/``), handing tracks over on /mlkm/handoff ->
``track_merge`` (one view of every shard's tracks on /mlkm/tracks) -> ``scorer_node`` in
stream mode, and ``bag_recorder``. The source waits until every shard subscribed to its
stations and its margins. ``ros2 launch road_sensors shards.launch.py -s`` lists the
arguments.
"""

from road_sensors.launch_graph import (
    RECORD_ARGUMENTS,
    description,
    flag,
    node,
    recorder,
    source_timing,
)

ARGUMENTS = (
    ('shards', '4', 'association nodes the road is split over [-]'),
    (
        'scenario',
        'highway',
        'SUMO scenario: single_lane, highway, long_highway, congested or ramps [-]',
    ),
    ('duration', '300.0', 'simulated time the source publishes [s]'),
    ('stations', '40', 'sensor stations along the road [-]'),
    ('seed', '1', 'seed of the source [-]'),
    ('real_time_factor', '0.0', '1.0 = real time, 0 = as fast as delivery allows [-]'),
    ('start_delay', '1.0', 'pause of the source after its subscribers matched [s]'),
    ('method', 'multiframe', 'stream associator of every shard (stream_method) [-]'),
    ('lag', '30.0', 'links revisable until the newest stamp is this far past [s]'),
    ('quiet_flush', '0.0', 'flush a road quiet for this long (wall time); 0 = the lag [s]'),
    ('window', '60.0', 'scoring window of stamp time [s]'),
    *RECORD_ARGUMENTS,
)


def nodes(context):
    from mlkm_core.shards.regions import split_road

    arg = context.launch_configurations
    record = flag(arg['record'])
    count, stations = int(arg['shards']), int(arg['stations'])
    regions = split_road(stations, count)
    shards = [
        node(
            arg,
            'mlkm_assoc',
            'association_node',
            {
                'mode': 'stream',
                'stream_method': arg['method'],
                'lag': float(arg['lag']),
                'quiet_flush': float(arg['quiet_flush']),
                'shard_count': count,
                'shard_index': k,
                'source_namespace': '/',
                'wait_for_track_subscribers': 1,  # track_merge
            },
            namespace=f'shard_{k}',
        )
        for k in range(count)
    ]
    merge = node(
        arg,
        'mlkm_assoc',
        'track_merge',
        {
            'shard_count': count,
            'wait_for_track_subscribers': 1 + record + int(arg['track_subscribers']),
        },
    )
    source = {
        **source_timing(arg, record),
        'mode': 'continuous',
        'duration': float(arg['duration']),
        'scenario': arg['scenario'],
        'stations': stations,
        # every shard subscribed to its own stations and its margins (+ the recorder)
        'wait_for_subscriptions': sum(len(r.stations) for r in regions) + record * stations,
    }
    graph = [
        *shards,
        merge,
        node(arg, 'mlkm_assoc', 'scorer_node', {'mode': 'stream', 'window': float(arg['window'])}),
        node(arg, 'road_sensors', 'sumo_sensors', source),
    ]
    return [*graph, *recorder(arg)]


def generate_launch_description():
    return description(ARGUMENTS, nodes)
