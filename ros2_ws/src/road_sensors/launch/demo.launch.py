"""The demo graph: simulated sensors, association, scoring and a recorder, one process each.

    ros2 launch road_sensors demo.launch.py [episodes:=4] [method:=mlkm] [bag_dir:=bags/my_run]

The graph of ``make demo``: ``sensor_sim`` (the paper's Simulation 2, a few episodes) ->
``association_node`` -> ``scorer_node`` (accuracy per episode on /mlkm/score, in its log), and
``bag_recorder`` recording every topic. Each node reads its ``config/<node>.param.yaml`` and
then the arguments below. ``sensor_sim`` starts once the association node, the scorer and the
recorder subscribed, and exits after the last episode; the other nodes stay up until Ctrl-C,
which closes the bag. ``association_node`` holds its tracks until the scorer, the recorder and
``track_subscribers`` subscribers of yours matched /mlkm/tracks, so none of them misses one.
``ros2 launch road_sensors demo.launch.py -s`` lists the arguments.
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
    ('episodes', '4', 'episodes to simulate [-]'),
    ('seed', '0', 'seed of the layout and of every episode [-]'),
    ('targets', '50', 'targets per episode (sensor_sim n_targets) [-]'),
    ('sensors', '20', 'sensors along the road (sensor_sim n_sensors) [-]'),
    ('real_time_factor', '0.0', '1.0 = real time, 0 = as fast as delivery allows [-]'),
    ('start_delay', '1.0', 'pause of sensor_sim after its subscribers matched [s]'),
    ('method', 'mlkm', 'associator of association_node (mlkm, ...) [-]'),
    ('mode', 'episodes', 'association and scoring: episodes, stream or auto [-]'),
    ('segment_size', '5', 'sensors per road segment K [-]'),
    *RECORD_ARGUMENTS,
)


def nodes(context):
    arg = context.launch_configurations
    record = flag(arg['record'])
    graph = [
        # its tracks wait for the scorer (+ recorder) and the user's own subscribers
        association_node(
            arg,
            1 + record,
            {
                'method': arg['method'],
                'mode': arg['mode'],
                'segment_size': int(arg['segment_size']),
            },
        ),
        node(arg, 'mlkm_assoc', 'scorer_node', {'mode': arg['mode']}),
        node(
            arg,
            'road_sensors',
            'sensor_sim',
            {
                **source_timing(arg, record),
                'episodes': int(arg['episodes']),
                'n_targets': int(arg['targets']),
                'n_sensors': int(arg['sensors']),
            },
        ),
    ]
    return [*graph, *recorder(arg)]


def generate_launch_description():
    return description(ARGUMENTS, nodes)
