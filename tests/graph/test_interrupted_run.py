"""A pytest run that is killed (SIGTERM from a time limit, SIGHUP, SIGKILL) leaves none of
the processes its tests started: an inner pytest starts an association node through the
``ros_process`` fixture (the Proc launcher), the outer test kills the inner run and checks
that the node and its solver process are gone."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from process_group import group

pytestmark = [pytest.mark.ros, pytest.mark.slow]

CHILD = Path(__file__).with_name('interrupted_run_child.py')
#: Longest time from the end of the inner run to the end of every process it started [s].
BOUND = 15.0


def alive(pid: int) -> bool:
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != 'Z'


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGKILL], ids=['SIGTERM', 'SIGKILL'])
def test_killed_run_leaves_no_process(tmp_path, repo_root, sig) -> None:
    pid_file = tmp_path / 'node.pid'
    env = {**os.environ, 'MLKM_TEST_PID_FILE': str(pid_file)}
    inner = subprocess.Popen(
        [sys.executable, '-m', 'pytest', str(CHILD), '-q', '-p', 'no:cacheprovider',
         '-o', 'timeout=0', f'--basetemp={tmp_path / "inner"}'],
        cwd=repo_root, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        start_new_session=True,
    )  # fmt: skip
    started: list[int] = []
    try:
        deadline = time.monotonic() + 180.0
        while not pid_file.exists() or not pid_file.read_text():
            assert inner.poll() is None, inner.stdout.read().decode()
            assert time.monotonic() < deadline, 'the inner run did not start its node'
            time.sleep(0.05)
        node = int(pid_file.read_text())
        started = group(node)
        assert node in started and len(started) >= 2, started
        os.kill(inner.pid, sig)
        inner.wait(60.0)
        deadline = time.monotonic() + BOUND
        while any(alive(p) for p in started) and time.monotonic() < deadline:
            time.sleep(0.05)
        left = [p for p in started if alive(p)]
        assert not left, f'still running {BOUND:g} s after the run ended: {left}'
    finally:
        for pid in [inner.pid, *started]:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
        inner.wait(10.0)


@pytest.mark.parametrize('mode', ['episodes', 'stream'])
def test_helpers_die_with_a_killed_association_node(ros_process, mode) -> None:
    """SIGKILL of the node alone (not its group): its solver and tracker processes end too."""
    node = ros_process('mlkm_assoc', 'association_node', '--ros-args', '-p', f'mode:={mode}')
    want = 2 if mode == 'episodes' else 4  # the node, its solver; stream: tracker, its solver
    deadline = time.monotonic() + 120.0
    while len(group(node.pid)) < want:
        assert node.poll() is None, node.output()
        assert time.monotonic() < deadline, (group(node.pid), node.output())
        time.sleep(0.05)
    started = group(node.pid)
    os.kill(node.pid, signal.SIGKILL)
    node.wait(10.0)
    deadline = time.monotonic() + BOUND
    while any(alive(p) for p in started) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [p for p in started if alive(p)], node.output()
