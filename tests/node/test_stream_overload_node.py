"""The association node in stream mode with a tiny ``max_uncommitted``: every due boundary
is committed on the immediate links without a window solve, /diagnostics says so (WARN, the
skipped solves and forced commits), the tracks are still the vehicles, and the level is OK
again once the quiet road's flush took the backlog.
"""

from __future__ import annotations

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from test_stream_association import IDS, VEHICLES, Harness, passages

from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import Track

pytestmark = pytest.mark.ros


def test_overloaded_stream_commits_immediate_links_and_warns(rclpy_context, spin_until):
    h = Harness(rclpy_context, spin_until, mode='stream', lag=5.0, max_uncommitted=2)
    levels: list[tuple[int, dict[str, str]]] = []  # every diagnostics message, in order

    def on_diag(msg: DiagnosticArray) -> None:
        name = h.node.get_fully_qualified_name()
        values = conv.diagnostics_values(msg, name)
        if values is not None:
            [status] = [s for s in msg.status if s.name == name]
            levels.append((int.from_bytes(status.level, 'little'), values))

    h.test.create_subscription(
        DiagnosticArray, qos.DIAGNOSTICS_TOPIC, on_diag, qos.DIAGNOSTICS_QOS
    )
    try:
        h.start()
        # the tracker takes the detections well before the quiet road's flush
        h.wait(lambda: h.diag.get('stream.tracker_ready') == 'True', 120.0)
        rows = passages()
        for s, ns, v, _, lane, length in rows:
            h.detect(s, ns, v, lane, length)
        keys = {(IDS[s], lane, ns): vehicle for s, ns, _, vehicle, lane, _ in rows}
        # the road falls quiet: after the lag every track is FINAL
        h.wait(lambda: all(h.latest().get(k, (-1, -1))[1] == Track.STATUS_FINAL for k in keys))
        h.wait(lambda: h.diag.get('stream.working_set') == '0' and levels[-1][0] == 0)
    finally:
        h.close()
    warned = [v for level, v in levels if level == DiagnosticStatus.WARN[0]]
    assert warned, 'no WARN while the boundaries were committed without solves'
    assert warned[0]['stream.tracker.overloaded'] == '1'
    assert int(warned[0]['stream.tracker.skipped_solves']) > 0
    assert int(warned[0]['stream.tracker.forced_commits']) > 0
    assert levels[-1][1]['stream.tracker.overloaded'] == '0'  # the flush took the backlog
    # every committed link is a real one: each vehicle is one track of its own
    latest = h.latest()
    track_of: dict[int, set[int]] = {}
    for k, vehicle in keys.items():
        track_of.setdefault(vehicle, set()).add(latest[k][0])
    assert all(len(t) == 1 for t in track_of.values()) and len(track_of) == len(VEHICLES)
    assert len({next(iter(t)) for t in track_of.values()}) == len(VEHICLES)
