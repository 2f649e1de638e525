"""Not collected by ``make test``: the inner run of test_interrupted_run.py. It starts an
association node (which starts its solver process), writes the node's pid to
``$MLKM_TEST_PID_FILE`` once the helper is up, and holds until the run is killed."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

from process_group import group


def test_hold_a_node_until_killed(ros_process) -> None:
    node = ros_process('mlkm_assoc', 'association_node')
    deadline = time.monotonic() + 120.0
    while len(group(node.pid)) < 2:  # the node and its solver process
        assert node.poll() is None, node.output()
        assert time.monotonic() < deadline, node.output()
        time.sleep(0.05)
    Path(os.environ['MLKM_TEST_PID_FILE']).write_text(str(node.pid))
    threading.Event().wait()  # until the outer test kills this run
