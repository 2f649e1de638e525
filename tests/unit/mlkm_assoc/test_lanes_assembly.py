"""The join key (sensor, lane, stamp) in the association node's assembly and solver, without
ROS: two vehicles in different lanes passing one station within the same nanosecond are both
kept and associated, duplicates are refused, lanes and lengths are checked and reach the
core's Detections."""

from __future__ import annotations

import math

import numpy as np

from mlkm_assoc.assembly import Assembler, AssociationConfig, Job
from mlkm_assoc.solver import Solver, to_detections
from mlkm_core.types import Layout

S = 1_000_000_000
IDS = [10, 11, 12]
POS = [100.0, 200.0, 300.0]
LAYOUT = Layout(400.0, np.array(POS), np.array(IDS), ('a', 'b', 'c'))


class Rig:
    def __init__(self, lane_counts=(2, 2, 2), n: int = 2) -> None:
        self.jobs: list[Job] = []
        self.reasons: list[str] = []
        self.details: list[str] = []
        cfg = AssociationConfig(segment_size=3, completion_timeout=5.0)
        self.a = Assembler(cfg, self.jobs.append, self._on_reject)
        self.a.set_layout(LAYOUT, 0.0, 0, lane_counts)
        self.n = n
        self.a.add_episode(0, n, 0, 100 * S, None, 0.0, 1)

    def _on_reject(self, reason: str, detail: str) -> None:
        self.reasons.append(reason)
        self.details.append(detail)

    def det(self, s, stamp_ns, v, lane=-1, length=math.nan, position=None) -> None:
        pos = POS[s] if position is None else position
        self.a.add_detection(IDS[s], stamp_ns, pos, v, 0.0, lane, length)

    def end(self, counts) -> None:
        self.a.add_episode(0, self.n, 0, 100 * S, dict(zip(IDS, counts)), 0.0, 2)


def side_by_side(r: Rig) -> None:
    """A car (lane 1, 30 m/s, 4.5 m) and a truck (lane 0, 20 m/s, 16 m) side by side at
    sensor a at t = 10 s: the same nanosecond; then each at its own speed."""
    for s in range(3):
        dt = (POS[s] - POS[0]) / 30.0
        r.det(s, 10 * S + round(dt * S), 30.0, lane=1, length=4.5)
        dt = (POS[s] - POS[0]) / 20.0
        r.det(s, 10 * S + round(dt * S), 20.0, lane=0, length=16.0)


def test_same_nanosecond_in_two_lanes_both_kept_and_associated() -> None:
    r = Rig()
    side_by_side(r)
    assert r.reasons == [] and r.a.accepted == 6
    r.end([2, 2, 2])
    assert [j.kind for j in r.jobs] == ['segment', 'final']
    part = r.jobs[0].parts[0]
    assert part.stamps_ns[:2].tolist() == [10 * S, 10 * S]
    assert part.lanes[:2].tolist() == [0, 1]
    assert part.lengths[:2].tolist() == [16.0, 4.5]
    core = to_detections(part)
    assert core.lane.tolist() == part.lanes.tolist()
    assert core.length.tolist() == part.lengths.tolist()
    result = Solver().run(r.jobs[0])
    assert result.lanes.tolist() == part.lanes.tolist()
    # One track per vehicle: every lane-1 detection in one track, every lane-0 in the other.
    labels = result.labels
    car, truck = labels[result.lanes == 1], labels[result.lanes == 0]
    assert car.size == truck.size == 3
    assert len(set(car.tolist())) == 1 and len(set(truck.tolist())) == 1
    assert car[0] != truck[0] and car[0] >= 0 and truck[0] >= 0


def test_duplicate_is_same_sensor_lane_and_stamp() -> None:
    r = Rig()
    r.det(0, 10 * S, 30.0, lane=1)
    r.det(0, 10 * S, 25.0, lane=1)  # same sensor, lane, stamp: a duplicate
    r.det(0, 10 * S, 25.0, lane=0)  # another lane: kept
    r.det(1, 10 * S, 25.0, lane=0)  # another sensor: kept
    assert r.reasons == ['duplicate']
    assert r.a.accepted == 3


def test_duplicate_without_lane_is_same_sensor_stamp_and_velocity() -> None:
    r = Rig(lane_counts=None)
    r.det(0, 10 * S, 30.0)
    r.det(0, 10 * S, 25.0)  # lane unknown, another velocity: another vehicle
    r.det(0, 10 * S, 30.0)  # the same sensor, stamp and velocity: a duplicate
    r.det(0, 10 * S, 30.0, lane=0)  # a known lane is another key
    assert r.reasons == ['duplicate']
    assert r.a.accepted == 3


def test_lane_outside_the_station_is_rejected_with_reason() -> None:
    r = Rig(lane_counts=(2, 3, 1))
    r.det(0, 10 * S, 30.0, lane=2)  # station a has lanes 0, 1
    r.det(1, 11 * S, 30.0, lane=2)  # station b has three
    r.det(2, 12 * S, 30.0, lane=-2)
    r.det(2, 13 * S, 30.0, lane=-1)
    assert r.reasons == ['lane_out_of_range', 'lane_out_of_range']
    assert 'lane 2' in r.details[0] and 'in [0, 1]' in r.details[0]
    assert r.a.rejected['lane_out_of_range'] == 2 and r.a.accepted == 2


def test_any_lane_accepted_when_the_layout_gives_no_lane_counts() -> None:
    r = Rig(lane_counts=None)
    r.det(0, 10 * S, 30.0, lane=7)
    assert r.reasons == [] and r.a.accepted == 1


def test_length_outside_bounds_is_rejected_unknown_accepted() -> None:
    r = Rig()
    r.det(0, 10 * S, 30.0, lane=0, length=250.0)
    r.det(0, 11 * S, 30.0, lane=0, length=-3.0)
    r.det(0, 12 * S, 30.0, lane=0, length=math.nan)
    r.det(0, 13 * S, 30.0, lane=0, length=0.0)
    r.det(0, 14 * S, 30.0, lane=0, length=12.0)
    assert r.reasons == ['length_out_of_range', 'length_out_of_range']
    assert 'vehicle length outside' in r.details[0]
    assert r.a.accepted == 3


def test_layout_with_other_lane_counts_is_a_new_layout() -> None:
    r = Rig(lane_counts=(2, 2, 2))
    assert not r.a.set_layout(LAYOUT, 1.0, 0, (2, 2, 2))
    assert r.a.set_layout(LAYOUT, 1.0, 0, (3, 2, 2))
    r.a.add_episode(0, 2, 0, 100 * S, None, 1.0, 5)
    r.det(0, 10 * S, 30.0, lane=2)
    assert r.reasons == []


def test_rerun_keeps_track_ids_of_same_nanosecond_detections() -> None:
    """A late detection forces a from-scratch rerun; the two same-stamp detections keep
    their track ids (the solver's alignment key includes the lane)."""
    r = Rig(n=2)
    side_by_side(r)
    solver = Solver()
    first = solver.run(r.jobs[0])
    r.det(0, 90 * S, 25.0, lane=0, length=5.0)  # clutter after the segment went out
    r.end([3, 2, 2])
    assert r.jobs[-1].kind == 'rerun'
    final = solver.run(r.jobs[-1])
    before = dict(zip(zip(first.stamps_ns.tolist(), first.lanes.tolist()), first.labels))
    after = dict(zip(zip(final.stamps_ns.tolist(), final.lanes.tolist()), final.labels))
    assert after[(10 * S, 0)] == before[(10 * S, 0)]
    assert after[(10 * S, 1)] == before[(10 * S, 1)]
    assert final.lengths.size == 7
