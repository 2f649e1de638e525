"""The solver logic in process, without ROS: stable track ids, the rerun path, errors."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from mlkm_assoc.assembly import Assembler, AssociationConfig, Job
from mlkm_assoc.solver import Solver, stable_ids
from mlkm_core.types import UNASSIGNED, Layout

S = 1_000_000_000
POS = [100.0, 200.0, 300.0, 400.0]
LAYOUT = Layout(500.0, np.array(POS), np.array([10, 11, 12, 13]), ('a', 'b', 'c', 'd'))
#: target -> (entry time [s], speed [m/s]); far apart in time: the answer is certain.
TARGETS = {0: (0.0, 10.0), 1: (50.0, 20.0), 2: (100.0, 40.0)}


def jobs_for(method: str, late: bool = False) -> list[Job]:
    """The jobs the assembler makes of one clean episode (segments of 2 sensors); with
    ``late``, one extra detection at sensor a after its segment went out (a rerun)."""
    jobs: list[Job] = []
    a = Assembler(AssociationConfig(method=method, segment_size=2), jobs.append)
    a.set_layout(LAYOUT, 0.0)
    a.add_episode(0, 3, 0, 200 * S, None, 0.0)
    for s, p in enumerate(POS):
        for t0, v in TARGETS.values():
            a.add_detection(int(LAYOUT.sensor_ids[s]), int((t0 + p / v) * S), p, v, 0.0)
    counts = {10: 4 if late else 3, 11: 3, 12: 3, 13: 3}
    a.add_episode(0, 3, 0, 200 * S, counts, 0.0)
    if late:
        a.add_detection(10, 150 * S, 100.0, 30.0, 0.0)
    return jobs


def track_of(result) -> dict[tuple[int, int], int]:
    return dict(
        zip(
            zip(result.sensor_index.tolist(), result.stamps_ns.tolist()),
            result.labels.tolist(),
        )
    )


def true_targets() -> dict[tuple[int, int], int]:
    return {
        (s, int((t0 + p / v) * S)): k for s, p in enumerate(POS) for k, (t0, v) in TARGETS.items()
    }


def assert_right(result) -> None:
    got = track_of(result)
    groups: dict[int, set[int]] = {}
    for key, target in true_targets().items():
        groups.setdefault(target, set()).add(got[key])
    assert all(len(g) == 1 and UNASSIGNED not in g for g in groups.values()), groups
    assert len({next(iter(g)) for g in groups.values()}) == 3


def test_stable_ids_follow_the_previous_update() -> None:
    previous = np.array([5, 5, 7, 7, UNASSIGNED])
    labels = np.array([0, 0, 1, 1, 1, 2, 2])  # renumbered by the associator, two new ones
    assert stable_ids(previous, labels).tolist() == [5, 5, 7, 7, 7, 8, 8]
    swapped = np.array([1, 1, 0, 0, UNASSIGNED])
    assert stable_ids(previous, swapped).tolist() == [5, 5, 7, 7, UNASSIGNED]


def test_track_ids_stable_from_partial_to_final() -> None:
    jobs = jobs_for('kmeans_pp')
    assert [j.kind for j in jobs] == ['segment', 'segment', 'final']
    solver = Solver()
    results = [solver.run(j) for j in jobs]
    partial, second, final = results
    assert not partial.final and final.final
    assert (partial.segments_done, second.segments_done, final.segments_done) == (1, 2, 2)
    assert partial.labels.size == 6 and final.labels.size == 12
    assert_right(final)
    first_ids = track_of(partial)
    assert all(track_of(final)[k] == v for k, v in first_ids.items())
    assert all(r.error is None for r in results)


def test_rerun_associates_everything_again_and_keeps_the_ids() -> None:
    jobs = jobs_for('mlkm', late=True)
    assert [j.kind for j in jobs] == ['segment', 'segment', 'rerun']
    solver = Solver()
    results = [solver.run(j) for j in jobs]
    partial, final = results[0], results[-1]
    assert final.final and final.labels.size == 13
    assert (0, 150 * S) in track_of(final)  # the late detection is in the final output
    assert_right(final)
    assert all(track_of(final)[k] == v for k, v in track_of(partial).items())


def test_associator_failure_is_reported_and_labels_unassigned() -> None:
    job = jobs_for('mlkm')[0]
    bad = Job(**{**job.__dict__, 'method': 'no_such_method'})
    result = Solver().run(bad)
    assert result.error is not None and 'episode 0, segment 0' in result.error
    assert 'no_such_method' in result.error
    assert result.labels.tolist() == [UNASSIGNED] * 6


def test_solver_module_is_ros_free() -> None:
    code = (
        'import sys, mlkm_assoc.solver\n'
        'bad = [m for m in sys.modules if m.split(".")[0] in '
        '("rclpy", "mlkm_ros", "road_sensor_msgs", "rosidl_runtime_py")]\n'
        'print(bad)\n'
        'sys.exit(1 if bad else 0)\n'
    )
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_track_ids_of_partials_are_kept_or_retired_in_the_final():
    """Episode 0 of the demo (50 targets, 20 sensors, seed 0): MLKM links two clusters of the
    first segment into one track after the second, so ids of a partial vanish. Every id a
    partial carried is in the final or named retired there, and no retired id is reused."""
    from mlkm_core.simulator import SimConfig, simulate_episodes

    data = simulate_episodes(SimConfig(), 0, 1)[0]
    layout, det = data.layout, data.detections
    origin = int(np.ceil(-det.stamp.min())) * S  # stamps >= 0, as sensor_sim shifts them
    jobs: list[Job] = []
    a = Assembler(AssociationConfig(method='mlkm', segment_size=5), jobs.append)
    a.set_layout(layout, 0.0)
    end = origin + int((det.stamp.max() + 1.0) * S)
    a.add_episode(0, 50, 0, end, None, 0.0)
    for i in np.argsort(det.stamp, kind='stable'):
        s = int(det.sensor_index[i])
        a.add_detection(
            int(layout.sensor_ids[s]), origin + int(det.stamp[i] * S), float(layout.positions[s]),
            float(det.velocity[i]), 0.0,
        )  # fmt: skip
    counts = {int(k): int((det.sensor_index == s).sum()) for s, k in enumerate(layout.sensor_ids)}
    a.add_episode(0, 50, 0, end, counts, 0.0)
    solver = Solver()
    results = [solver.run(job) for job in jobs]
    assert [r.final for r in results] == [False] * 4 + [True]
    seen: set[int] = set()
    for r in results:
        ids = set(np.unique(r.labels[r.labels >= 0]).tolist())
        assert set(r.retired) == seen - ids
        assert not ids & set(r.retired)
        seen |= ids
    final = results[-1]
    assert final.retired, 'this episode is expected to retire ids (else pick another)'
    partial_ids = {int(x) for r in results[:-1] for x in r.labels if x >= 0}
    final_ids = set(final.labels[final.labels >= 0].tolist())
    assert partial_ids <= final_ids | set(final.retired)
    # a fresh id is never one that was retired before
    for earlier, later in zip(results, results[1:]):
        fresh = set(later.labels[later.labels >= 0].tolist()) - set(
            earlier.labels[earlier.labels >= 0].tolist()
        )
        assert not fresh & set(earlier.retired)
