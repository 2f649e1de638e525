"""Reading trajectories (``mlkm_core.trajectories``) from tiny hand-written files.

Every expectation is computed by hand: feet to metres (10 ft = 3.048 m), NGSIM frames to
seconds (Frame_ID * 0.1 s), lanes counted from the right.
"""

import gzip

import numpy as np
import pytest

from mlkm_core.trajectories import TrajectoryError, read_trajectories
from mlkm_core.types import UNKNOWN_LANE

CSV = """vehicle_id,time_s,y_m,speed_mps,lane_id,length_m
7,0.1,12.0,9.5,1,4.5
7,0.0,11.0,10.0,1,4.5
3,0.0,50.0,8.0,3,
3,0.1,50.8,,2,12.25
"""


def _write(tmp_path, text, name='t.csv'):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_trajectory_csv_sorted_by_vehicle_and_time_lanes_from_the_right(tmp_path):
    t = read_trajectories(_write(tmp_path, CSV))
    assert t.vehicle.tolist() == [3, 3, 7, 7]
    assert t.time.tolist() == [0.0, 0.1, 0.0, 0.1]
    assert t.position.tolist() == [50.0, 50.8, 11.0, 12.0]
    assert t.speed[0] == 8.0 and np.isnan(t.speed[1])  # empty: unknown
    assert t.speed[2:].tolist() == [10.0, 9.5]
    # the largest lane id (3) is the road's lane count: id 1 (leftmost) -> 2, id 3 -> 0
    assert t.lane.tolist() == [0, 1, 2, 2]
    assert np.isnan(t.length[0]) and t.length[1:].tolist() == [12.25, 4.5, 4.5]
    assert len(t) == 4 and t.n_vehicles == 2


def test_trajectory_csv_lanes_option_columns_in_any_order_and_gzip(tmp_path):
    text = (
        'speed_mps,vehicle_id,time_s,y_m,lane_id,length_m,extra\n10,1,0,5,2,4,x\n10,1,1,15,,4,y\n'
    )
    path = tmp_path / 't.csv.gz'
    path.write_bytes(gzip.compress(text.encode()))
    t = read_trajectories(path, lanes=6)
    assert t.position.tolist() == [5.0, 15.0]
    assert t.lane.tolist() == [4, UNKNOWN_LANE]  # id 2 on a 6-lane road; empty: unknown


def test_the_shipped_ngsim_extract():
    from pathlib import Path

    path = Path(__file__).resolve().parents[3] / 'data/ngsim_i80/i80_trajectories_a.csv.gz'
    t = read_trajectories(path)
    # the data README: 111 vehicles, 55,364 rows, lanes 1-3, 0-261 s
    assert (len(t), t.n_vehicles) == (55364, 111)
    assert sorted(np.unique(t.lane).tolist()) == [0, 1, 2]
    assert (t.position.min(), t.position.max()) == (10.78, 507.2)
    assert t.time.min() == 0.0 and 260 < t.time.max() < 262


NGSIM_HEADER = (
    'Vehicle_ID,Frame_ID,Total_Frames,Global_Time,Local_X,Local_Y,Global_X,Global_Y,'
    'v_Length,v_Width,v_Class,v_Vel,v_Acc,Lane_ID,Preceding,Following,Space_Hdwy,Time_Hdwy'
)
# vehicle 5: frames 12, 13 at 10 ft and 20 ft, 100 ft/s, lane 1 (leftmost), 15 ft long;
# vehicle 2: frame 12 at 30 ft, 50 ft/s, lane 2, 20 ft long
NGSIM_ROWS = [
    '5,12,2,0,6.0,10.0,0,0,15.0,6.0,2,100.0,0,1,0,0,0,0',
    '5,13,2,0,6.0,20.0,0,0,15.0,6.0,2,100.0,0,1,0,0,0,0',
    '2,12,1,0,6.0,30.0,0,0,20.0,6.0,2,50.0,0,2,0,0,0,0',
]


def _check_ngsim(t):
    assert t.vehicle.tolist() == [2, 5, 5]
    assert t.time == pytest.approx([1.2, 1.2, 1.3])
    assert t.position == pytest.approx([9.144, 3.048, 6.096])
    assert t.speed == pytest.approx([15.24, 30.48, 30.48])
    assert t.length == pytest.approx([6.096, 4.572, 4.572])
    return t


def test_ngsim_with_its_header_in_feet(tmp_path):
    t = _check_ngsim(read_trajectories(_write(tmp_path, '\n'.join([NGSIM_HEADER, *NGSIM_ROWS]))))
    # lane ids 1, 2 on a road of 2 lanes (the largest id): 1 (leftmost) -> 1, 2 -> 0
    assert t.lane.tolist() == [0, 1, 1]


def test_ngsim_without_header_whitespace_separated(tmp_path):
    body = '\n'.join('   '.join(r.split(',')) for r in NGSIM_ROWS) + '\n'
    t = _check_ngsim(read_trajectories(_write(tmp_path, body, 'trajectories-0400-0415.txt'), 7))
    assert t.lane.tolist() == [5, 6, 6]  # on 7 lanes: id 1 -> 6, id 2 -> 5


def test_ngsim_header_matched_without_case_and_with_an_index_column(tmp_path):
    # the data.transportation.gov release: a leading index column, 'v_length'
    header = ',' + NGSIM_HEADER.replace('v_Length', 'v_length') + ',Location'
    rows = [f'{k},{r},i-80' for k, r in enumerate(NGSIM_ROWS)]
    _check_ngsim(read_trajectories(_write(tmp_path, '\n'.join([header, *rows]))))


FCD = """<?xml version="1.0" encoding="UTF-8"?>
<fcd-export>
    <timestep time="0.00">
        <vehicle id="car_b" x="10.00" y="-1.60" speed="12.00" lane="m0_2" distance="110.0"/>
    </timestep>
    <timestep time="0.50">
        <vehicle id="car_b" x="16.00" y="-1.60" speed="12.00" lane="m0_1" distance="116.0"/>
        <vehicle id="car_a" x="2.00" y="-1.60" speed="20.00" lane=":J1_0_0" length="7.5"
            distance="102.0"/>
    </timestep>
    <timestep time="1.00">
        <vehicle id="car_a" x="12.00" y="-1.60" speed="20.00" lane="e" distance="112.0"/>
    </timestep>
</fcd-export>
"""


def test_sumo_fcd_ids_by_first_appearance_lane_index_from_the_lane_id(tmp_path):
    t = read_trajectories(_write(tmp_path, FCD, 'fcd.xml'))
    # ids in the order vehicles first appear: car_b -> 0, car_a -> 1
    assert t.vehicle.tolist() == [0, 0, 1, 1]
    assert t.time.tolist() == [0.0, 0.5, 0.5, 1.0]
    assert t.position.tolist() == [10.0, 16.0, 2.0, 12.0]
    assert t.speed.tolist() == [12.0, 12.0, 20.0, 20.0]
    # m0_2 -> 2, m0_1 -> 1, an internal lane :J1_0_0 -> 0, no index -> unknown
    assert t.lane.tolist() == [2, 1, 0, UNKNOWN_LANE]
    assert np.isnan(t.length[[0, 1, 3]]).all() and t.length[2] == 7.5


def test_sumo_fcd_distance_as_the_position(tmp_path):
    t = read_trajectories(_write(tmp_path, FCD, 'fcd.xml'), fcd_position='distance')
    assert t.position.tolist() == [110.0, 116.0, 102.0, 112.0]
    no_distance = FCD.replace(' distance="110.0"', '')
    with pytest.raises(TrajectoryError, match=r'fcd\.xml: FCD vehicle without .distance.'):
        read_trajectories(_write(tmp_path, no_distance, 'fcd.xml'), fcd_position='distance')
    with pytest.raises(TrajectoryError, match='x or distance'):
        read_trajectories(_write(tmp_path, FCD, 'fcd.xml'), fcd_position='y')


@pytest.mark.parametrize(
    ('text', 'name', 'message'),
    [
        ('vehicle_id,time_s,y_m,lane_id,length_m\n1,0,0,1,4\n', 't.csv', r't\.csv: .*speed_mps'),
        (
            'vehicle_id,time_s,y_m,speed_mps,lane_id,length_m\n1,0,0,5,1,4\n\n1,0.1,abc,5,1,4\n',
            't.csv',
            r't\.csv, line 4: not 6 numbers',
        ),
        (
            'vehicle_id,time_s,y_m,speed_mps,lane_id,length_m\n1,0,0,5,1,4\n2,0,3,5,1,4\n'
            '1,0,1,5,1,4\n',
            't.csv',
            r't\.csv: vehicle 1 has two frames at 0 s \(lines 2 and 4\)',
        ),
        (
            NGSIM_HEADER + '\n' + NGSIM_ROWS[0] + '\n\n' + NGSIM_ROWS[1].replace('20.0', 'x'),
            'n.csv',
            r'n\.csv, line 4: not an NGSIM row',
        ),
        (
            NGSIM_HEADER.replace('Local_Y', 'Local_Z') + '\n' + NGSIM_ROWS[0],
            'n.csv',
            r'n\.csv: NGSIM file without column\(s\) Local_Y',
        ),
        ('\n'.join([NGSIM_ROWS[0], NGSIM_ROWS[0]]), 'n.txt', r'n\.txt: .*two frames.*lines 1'),
        ('<fcd-export><timestep time="0"><vehicle id="a"', 'f.xml', r'f\.xml: not a SUMO FCD'),
        (
            '<fcd-export><timestep time="0"><vehicle id="a" x="1" speed="fast" lane="e_0"/>'
            '</timestep></fcd-export>',
            'f.xml',
            r'f\.xml: FCD vehicle with a missing or bad',
        ),
        ('<fcd-export></fcd-export>', 'f.xml', r'f\.xml: no frames'),
        ('vehicle_id,time_s,y_m,speed_mps,lane_id,length_m\n', 't.csv', r't\.csv: no frames'),
        ('time,place\n1,2\n', 't.csv', r't\.csv: neither a trajectory CSV'),
        (
            'vehicle_id,time_s,y_m,speed_mps,lane_id,length_m\n1.5,0,0,5,1,4\n',
            't.csv',
            r't\.csv: every vehicle id must be a whole number',
        ),
        (
            'vehicle_id,time_s,y_m,speed_mps,lane_id,length_m\n1,,0,5,1,4\n',
            't.csv',
            r't\.csv: every frame needs a finite time and position',
        ),
    ],
)
def test_errors_name_the_file_and_line(tmp_path, text, name, message):
    with pytest.raises(TrajectoryError, match=message):
        read_trajectories(_write(tmp_path, text, name))


def test_more_lane_ids_than_lanes_and_missing_files_are_refused(tmp_path):
    with pytest.raises(TrajectoryError, match=r't\.csv: lane id 3 on a 2-lane road'):
        read_trajectories(_write(tmp_path, CSV), lanes=2)
    with pytest.raises(TrajectoryError, match=r'nothing\.csv: No such file'):
        read_trajectories(tmp_path / 'nothing.csv')
    (tmp_path / 'bad.gz').write_bytes(b'\x1f\x8b' + b'not gzip at all')
    with pytest.raises(TrajectoryError, match=r'bad\.gz: not a readable gzip file'):
        read_trajectories(tmp_path / 'bad.gz')
