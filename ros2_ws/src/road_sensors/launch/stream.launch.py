"""The open-road graph: SUMO sensor stations, stream association, scoring and a recorder.

    ros2 launch road_sensors stream.launch.py [duration:=120.0] [lag:=30.0] [source:=sim]
    ros2 launch road_sensors stream.launch.py network:=interchange

The graph of ``make demo-stream``: ``sumo_sensors`` in continuous mode on a SUMO scenario
(``source:=sim``: ``sensor_sim``'s open road instead; ``network:=...``: continuous traffic on
a SUMO road network) -> ``association_node`` in stream mode
(every detection linked at once, links committed ``lag`` seconds of stamp time later) ->
``scorer_node`` in stream mode (accuracy and revision rate per ``window`` of stamp time on
/mlkm/score), and ``bag_recorder``. Each node reads its ``config/<node>.param.yaml`` and then the
arguments below. The source exits after ``duration`` simulated seconds; the association node
flushes the quiet road ``lag`` (or ``quiet_flush``) seconds later and the scorer scores the
last window; the other nodes stay up until Ctrl-C, which closes the bag.
``ros2 launch road_sensors stream.launch.py -s`` lists the arguments.
"""

from road_sensors.launch_graph import (
    RECORD_ARGUMENTS,
    association_node,
    description,
    flag,
    node,
    recorder,
    source_timing,
)

ARGUMENTS = (
    ('source', 'sumo', 'sumo (sumo_sensors) or sim (sensor_sim continuous) [-]'),
    (
        'scenario',
        'ramps',
        'SUMO scenario: single_lane, highway, long_highway, congested or ramps [-]',
    ),
    (
        'network',
        '',
        'SUMO: a road network instead of the scenario: interchange, arterial or grid (linked '
        'with assignment, the network stream) [-]',
    ),
    ('duration', '120.0', 'simulated time the source publishes [s]'),
    ('stations', '10', 'sensor stations along the road [-]'),
    ('stations_at', '', "SUMO: station positions instead, e.g. '300,700,1100' [m]"),
    ('seed', '1', 'seed of the source [-]'),
    ('real_time_factor', '0.0', '1.0 = real time, 0 = as fast as delivery allows [-]'),
    ('start_delay', '1.0', 'pause of the source after its subscribers matched [s]'),
    ('method', 'multiframe', 'stream associator of association_node (stream_method) [-]'),
    ('lag', '30.0', 'links revisable until the newest stamp is this far past [s]'),
    ('quiet_flush', '0.0', 'flush a road quiet for this long (wall time); 0 = the lag [s]'),
    ('window', '30.0', 'scoring window of stamp time [s]'),
    *RECORD_ARGUMENTS,
)


def nodes(context):
    arg = context.launch_configurations
    record = flag(arg['record'])
    if arg['source'] not in ('sumo', 'sim'):
        raise ValueError(f'source:={arg["source"]}: choose sumo or sim')
    source = {
        **source_timing(arg, record),
        'mode': 'continuous',
        'duration': float(arg['duration']),
    }
    if arg['source'] == 'sumo':
        executable = 'sumo_sensors'
        source.update(
            scenario=arg['scenario'],
            network=arg['network'],
            stations=int(arg['stations']),
            stations_at=arg['stations_at'],
        )
    else:
        executable = 'sensor_sim'
        source.update(n_sensors=int(arg['stations']))
    graph = [
        # its tracks wait for the scorer (+ recorder) and the user's own subscribers
        association_node(
            arg,
            1 + record,
            {
                'mode': 'stream',
                'stream_method': arg['method'],
                'lag': float(arg['lag']),
                'quiet_flush': float(arg['quiet_flush']),
            },
        ),
        node(arg, 'mlkm_assoc', 'scorer_node', {'mode': 'stream', 'window': float(arg['window'])}),
        node(arg, 'road_sensors', executable, source),
    ]
    return [*graph, *recorder(arg)]


def generate_launch_description():
    return description(ARGUMENTS, nodes)
