"""bag_recorder and bag_player leave ROS_AUTOMATIC_DISCOVERY_RANGE to the user.

The loopback default belongs to env.sh, the launchers and the test fixtures: an executable that
sets it for itself would silently turn a multi-machine recording into a local one. Each main()
runs in-process with ``rclpy.init`` replaced by a probe that records the discovery range the
middleware would see and then stops main(): no DDS participant is ever created, so nothing can
reach the network whatever the range.
"""

from __future__ import annotations

import os
import signal

import pytest
import rclpy

from rosbag_mcap import player, recorder


class _StopMain(Exception):
    """Raised by the probe so that main() ends before any node exists."""


@pytest.fixture
def probe_init(monkeypatch):
    seen: list[str | None] = []

    def fake_init(*_args, **_kwargs):
        seen.append(os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE'))
        raise _StopMain

    monkeypatch.setattr(rclpy, 'init', fake_init)
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield seen
    for signum, handler in handlers.items():
        signal.signal(signum, handler)


@pytest.mark.parametrize('module', [recorder, player], ids=['bag_recorder', 'bag_player'])
@pytest.mark.parametrize('user_value', [None, 'SUBNET', 'SYSTEM_DEFAULT'])
def test_main_passes_the_users_discovery_range_unchanged(
    module, user_value, probe_init, monkeypatch
):
    if user_value is None:
        monkeypatch.delenv('ROS_AUTOMATIC_DISCOVERY_RANGE', raising=False)
    else:
        monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', user_value)
    before = dict(os.environ)
    with pytest.raises(_StopMain):
        module.main(['bag', '--ros-args', '-p', 'bag:=/nonexistent'])
    assert probe_init == [user_value]
    assert dict(os.environ) == before
