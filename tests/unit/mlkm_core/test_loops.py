"""Virtual loops (``mlkm_core.loops``) on hand-made trajectories with hand-computed crossings,
and once on a real SUMO FCD output."""

import subprocess

import numpy as np
import pytest

from mlkm_core.loops import covered_span, even_positions, frame_step, virtual_loops
from mlkm_core.trajectories import Trajectories, read_trajectories
from mlkm_core.types import UNKNOWN_LANE


def _traj(*vehicles):
    """Trajectories from ``(id, times, positions, speeds[, lanes[, lengths]])`` tuples."""
    cols = [[] for _ in range(6)]
    for v in vehicles:
        vid, t, p, s = v[:4]
        n = len(t)
        lanes = v[4] if len(v) > 4 else [0] * n
        lengths = v[5] if len(v) > 5 else [4.0] * n
        for c, values in zip(cols, ([vid] * n, t, p, s, lanes, lengths), strict=True):
            c.extend(values)
    return Trajectories.build(*cols)


def _by_station(loops):
    """{station index: [(vehicle, stamp, speed, lane, length), ...]} in stamp order."""
    d = loops.dataset.detections
    out = {}
    for k in range(len(d)):
        out.setdefault(int(d.sensor_index[k]), []).append(
            (int(d.target[k]), float(d.stamp[k]), float(d.velocity[k]), int(d.lane[k]),
             float(d.length[k]))
        )  # fmt: skip
    return out


def test_crossing_time_and_speed_interpolated_lane_and_length_from_the_nearer_frame():
    # frames at t = 0 and 0.1 s, at 9 m and 11 m, 10 m/s then 20 m/s, lane 0 then 1
    traj = _traj((1, [0.0, 0.1], [9.0, 11.0], [10.0, 20.0], [0, 1], [4.0, 5.0]))
    got = _by_station(virtual_loops(traj, [9.5, 10.0, 10.5, 11.0]))
    # f = (x - 9) / 2: stamp 0.1 f, speed 10 + 10 f; lane/length of frame 0 for f <= 0.5
    assert got[0] == [(1, 0.025, 12.5, 0, 4.0)]
    assert got[1] == [(1, 0.05, 15.0, 0, 4.0)]  # halfway: the earlier frame
    assert got[2] == [(1, 0.075, 17.5, 1, 5.0)]
    assert got[3] == [(1, 0.1, 20.0, 1, 5.0)]  # a frame right on the station: f = 1


def test_a_vehicle_first_seen_on_or_past_a_station_is_not_detected_there():
    traj = _traj((1, [0.0, 1.0, 2.0], [10.0, 20.0, 30.0], [10.0] * 3))
    loops = virtual_loops(traj, [5.0, 10.0, 25.0])
    assert _by_station(loops) == {2: [(1, 1.5, 10.0, 0, 4.0)]}
    assert loops.vehicles_detected == 1 and loops.dataset.n_targets == 1


def test_a_stopped_vehicle_jittering_across_a_station_is_counted_once():
    # 9.9 -> 10.1 crosses 10 m (t 0.1 .. 0.2), back to 9.95, across again to 10.05
    p = [9.0, 9.9, 10.1, 9.95, 10.05, 10.2, 12.0]
    traj = _traj((4, [0.1 * k for k in range(7)], p, [1.0] * 7))
    got = _by_station(virtual_loops(traj, [10.0]))
    assert len(got[0]) == 1
    vehicle, stamp, *_ = got[0][0]
    assert (vehicle, stamp) == (4, 0.15)  # the first crossing, halfway through 0.1 .. 0.2 s


def test_a_gap_in_the_frames_hides_the_stations_passed_unseen():
    # seen until 90 m at t = 2 s, then again from 130 m at t = 6 s (frames every 1 s)
    t = [0.0, 1.0, 2.0, 6.0, 7.0, 8.0]
    p = [70.0, 80.0, 90.0, 130.0, 140.0, 150.0]
    traj = _traj((9, t, p, [10.0] * 6))
    assert frame_step(traj) == 1.0
    got = _by_station(virtual_loops(traj, [85.0, 100.0, 140.0]))
    assert got == {0: [(9, 1.5, 10.0, 0, 4.0)], 2: [(9, 7.0, 10.0, 0, 4.0)]}
    # the gap is 4 frame steps: tolerated (gap_factor 5), 100 m is crossed at 2 + 4 * 10/40 s
    wide = _by_station(virtual_loops(traj, [100.0], gap_factor=5.0))
    assert wide == {0: [(9, 3.0, 10.0, 0, 4.0)]}


def test_open_loops_keep_every_crossing_closed_only_the_vehicles_seen_at_every_station():
    traj = _traj(
        (1, [0.0, 1.0, 2.0, 3.0], [5.0, 15.0, 25.0, 35.0], [10.0] * 4),  # passes 10, 20, 30
        (2, [0.0, 1.0, 2.0], [2.0, 12.0, 22.0], [10.0] * 3),  # seen until 22 m: 10, 20
        (3, [1.0, 2.0, 3.0], [16.0, 26.0, 36.0], [10.0] * 3),  # seen from 16 m: 20, 30
        (4, [0.0, 1.0], [40.0, 50.0], [10.0] * 2),  # past every station
    )
    stations = [10.0, 20.0, 30.0]
    opened = virtual_loops(traj, stations)
    d = opened.dataset.detections
    assert sorted(zip(d.sensor_index.tolist(), d.target.tolist(), d.stamp.tolist())) == [
        (0, 1, 0.5), (0, 2, 0.8), (1, 1, 1.5), (1, 2, 1.8), (1, 3, 1.4), (2, 1, 2.5),
        (2, 3, 2.4),
    ]  # fmt: skip
    assert (opened.vehicles_seen, opened.vehicles_detected, opened.dataset.n_targets) == (4, 3, 3)
    assert not opened.closed
    closed = virtual_loops(traj, stations, closed=True)
    c = closed.dataset.detections
    assert c.target.tolist() == [1, 1, 1] and c.stamp.tolist() == [0.5, 1.5, 2.5]
    assert (closed.vehicles_seen, closed.vehicles_detected, closed.dataset.n_targets) == (4, 1, 1)
    assert closed.closed


def test_detections_are_in_stamp_order_and_the_layout_covers_the_road():
    traj = _traj(
        (1, [0.0, 1.0, 2.0], [0.0, 10.0, 20.0], [10.0] * 3),
        (2, [0.0, 1.0, 2.0], [4.0, 14.0, 24.0], [10.0] * 3),
    )
    loops = virtual_loops(traj, [5.0, 12.0])
    d = loops.dataset.detections
    assert d.stamp.tolist() == [0.1, 0.5, 0.8, 1.2]
    assert d.sensor_index.tolist() == [0, 0, 1, 1] and d.target.tolist() == [2, 1, 2, 1]
    assert loops.dataset.layout.positions.tolist() == [5.0, 12.0]
    assert loops.dataset.layout.road_length == 24.0  # the furthest frame
    assert virtual_loops(traj, [5.0], road_length=100.0).dataset.layout.road_length == 100.0


def test_a_standstill_speed_is_replaced_by_the_mean_over_the_frame_interval():
    # both frames (nearly) at a standstill, yet the front moved 0.2 m across the loop in 10 s
    slow = _traj((1, [0.0, 10.0], [9.9, 10.1], [0.0, 0.005]))
    assert _by_station(virtual_loops(slow, [10.0])) == {0: [(1, 5.0, 0.02, 0, 4.0)]}
    # an unknown speed too
    unknown = _traj((1, [0.0, 10.0], [9.9, 10.1], [np.nan, np.nan]))
    assert _by_station(virtual_loops(unknown, [10.0]))[0][0][2] == 0.02
    # at the bound itself (interpolated 0.01 m/s) the frames' speed stands
    edge = _traj((1, [0.0, 10.0], [9.9, 10.1], [0.0, 0.02]))
    assert _by_station(virtual_loops(edge, [10.0]))[0][0][2] == 0.01


def test_several_stretches_of_one_vehicle():
    # stretch 1: 0..50 m at 10 m/s (t 0..5 s); stretch 2: 100..200 m (t 10..20 s)
    t = [float(k) for k in range(6)] + [float(k) for k in range(10, 21)]
    p = [10.0 * k for k in range(6)] + [100.0 + 10.0 * k for k in range(11)]
    traj = _traj((5, t, p, [10.0] * len(t)))
    loops = virtual_loops(traj, [25.0, 75.0, 150.0])
    assert _by_station(loops) == {0: [(5, 2.5, 10.0, 0, 4.0)], 2: [(5, 15.0, 10.0, 0, 4.0)]}
    assert virtual_loops(traj, [25.0, 75.0, 150.0], closed=True).dataset.detections.stamp.size == 0


def test_lanes_of_the_road_come_from_every_frame_and_values_are_rounded():
    # the vehicle in lane 2 never reaches the station: the road still has 3 lanes
    traj = _traj(
        (1, [0.0, 0.3], [0.0, 3.0], [10.0, 10.0], [0, 0], [4.5678, 4.5678]),
        (2, [0.0, 0.3], [20.0, 23.0], [10.0, 10.0], [2, 2], [4.0, 4.0]),
    )
    loops = virtual_loops(traj, [1.0])
    assert loops.lanes == 3
    # f = 1/3: stamp 0.1 s exactly to 1 ms, length to 1 cm
    assert _by_station(loops) == {0: [(1, 0.1, 10.0, 0, 4.57)]}
    unknown = _traj((1, [0.0, 1.0], [0.0, 2.0], [2.0, 2.0], [UNKNOWN_LANE] * 2))
    assert virtual_loops(unknown, [1.0]).lanes == 0


def test_even_positions_and_covered_span():
    assert even_positions(5, 50.0, 450.0).tolist() == [50.0, 150.0, 250.0, 350.0, 450.0]
    assert even_positions(1, 70.0, 10.0).tolist() == [70.0]
    for bad in ((0, 0.0, 10.0), (3, 10.0, 10.0)):
        with pytest.raises(ValueError):
            even_positions(*bad)
    traj = _traj((1, [0.0, 1.0], [100.0, 300.0], [1.0, 1.0]))
    assert covered_span(traj) == (110.0, 290.0)
    single = _traj((1, [0.0], [1.0], [1.0]))
    with pytest.raises(ValueError, match='no vehicle has two frames'):
        virtual_loops(single, [1.0])


NODES = """<nodes>
    <node id="a" x="0" y="0"/>
    <node id="b" x="1000" y="0"/>
</nodes>
"""
EDGES = """<edges>
    <edge id="m0" from="a" to="b" numLanes="1" speed="20"/>
</edges>
"""
DEPARTS = (0.0, 4.0, 8.0, 12.0)
ROUTES = (
    '<routes>\n    <vType id="car" length="5" maxSpeed="20" sigma="0" speedFactor="1" '
    'speedDev="0"/>\n'
    '    <route id="r" edges="m0"/>\n'
    + ''.join(
        f'    <vehicle id="v{k}" type="car" route="r" depart="{t}" departSpeed="max"/>\n'
        for k, t in enumerate(DEPARTS)
    )
    + '</routes>\n'
)


@pytest.mark.slow
def test_real_sumo_fcd_every_vehicle_at_every_station_in_departure_order(tmp_path):
    from mlkm_sumo.network import NETCONVERT_OPTIONS, binary, sumo_env

    (tmp_path / 'n.nod.xml').write_text(NODES)
    (tmp_path / 'n.edg.xml').write_text(EDGES)
    (tmp_path / 'n.rou.xml').write_text(ROUTES)
    net, fcd = tmp_path / 'n.net.xml', tmp_path / 'fcd.xml'
    for cmd in (
        [str(binary('netconvert')), '--node-files', 'n.nod.xml', '--edge-files', 'n.edg.xml',
         *NETCONVERT_OPTIONS, '--output-file', net.name],
        [str(binary('sumo')), '-n', net.name, '-r', 'n.rou.xml', '--fcd-output', fcd.name,
         '--fcd-output.distance', 'true', '--step-length', '0.5', '--no-step-log', 'true',
         '--end', '200'],
    ):  # fmt: skip
        out = subprocess.run(
            cmd, cwd=tmp_path, env=sumo_env(), capture_output=True, text=True, timeout=60
        )
        assert out.returncode == 0, out.stderr
    stations = [100.0, 400.0, 900.0]
    traj = read_trajectories(fcd)
    assert traj.n_vehicles == len(DEPARTS) and frame_step(traj) == 0.5
    loops = virtual_loops(traj, stations, closed=True)
    assert loops.vehicles_detected == len(DEPARTS) and loops.lanes == 1
    got = _by_station(loops)
    assert sorted(got) == [0, 1, 2]
    for rows in got.values():
        # SUMO vehicles are numbered as they first appear: v0 -> 0, ...
        assert [r[0] for r in rows] == list(range(len(DEPARTS)))
        assert all(r[2] == 20.0 and r[3] == 0 and np.isnan(r[4]) for r in rows)
    for k, depart in enumerate(DEPARTS):
        stamps = [got[s][k][1] for s in range(3)]
        # at 20 m/s (departSpeed max, speedFactor 1, sigma 0): stations 15 s and 25 s apart
        assert np.diff(stamps) == pytest.approx([15.0, 25.0], abs=1e-3)
        assert depart < stamps[0] < depart + 100.0 / 20.0 + 0.5
    # the road starts at x = 0: the distance driven is the same position
    by_distance = virtual_loops(read_trajectories(fcd, fcd_position='distance'), stations)
    np.testing.assert_allclose(
        by_distance.dataset.detections.stamp, loops.dataset.detections.stamp, atol=2e-3
    )
