"""ROS domains of the processes we start: a free domain id per graph, held machine-wide, and the
environment of a graph's processes (the domain, DDS on loopback only).

Parallel test workers, benchmark runs and demos on one machine each take a domain of their
own, so that no graph discovers another's nodes. Importing it loads no rclpy.
"""

from __future__ import annotations

import fcntl
import os
import random
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: A domain id held by a lock file here is in use on this machine (by any process).
LOCK_DIR = Path(os.environ.get('MLKM_DOMAIN_LOCK_DIR', '/tmp/mlkm-ros-domain-locks'))


@contextmanager
def reserve_domain() -> Iterator[int]:
    """A free ROS domain id (1..100), locked against every other holder on this machine."""
    LOCK_DIR.mkdir(parents=True, exist_ok=True)
    ids = list(range(1, 101))
    random.shuffle(ids)
    # Ids released longest ago by anyone on this machine first (a lock file's mtime is its last
    # release; one never made counts as oldest): whatever a finished holder may have left
    # behind in its domain (a participant that dies slowly, whose readers a new publisher
    # still counts as matched) then meets no new holder for a long time, even when the last
    # holder was another test session or another pytest worker.
    ids.sort(key=lambda i: _released_at(LOCK_DIR / f'{i}.lock'))
    for domain_id in ids:
        fd = os.open(LOCK_DIR / f'{domain_id}.lock', os.O_CREAT | os.O_RDWR, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        try:
            yield domain_id
        finally:
            os.utime(fd)  # the release time, for the next holder's choice
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)
        return
    raise RuntimeError('every ROS domain id 1..100 is in use on this machine')


def _released_at(lock: Path) -> int:
    """[ns] the last release of a domain id (its lock file's mtime); 0 if never held."""
    try:
        return lock.stat().st_mtime_ns
    except FileNotFoundError:
        return 0


@contextmanager
def domain() -> Iterator[int]:
    """The user's ROS_DOMAIN_ID if set, else a free one (1..100) held for the duration."""
    if os.environ.get('ROS_DOMAIN_ID'):
        yield int(os.environ['ROS_DOMAIN_ID'])
        return
    with reserve_domain() as domain_id:
        yield domain_id


def graph_env(domain_id: int) -> dict[str, str]:
    """os.environ with the domain, DDS on loopback only (unless the user chose otherwise, see
    mlkm_ros.network.loopback_env) and unbuffered I/O."""
    from mlkm_ros.network import loopback_env

    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain_id)
    loopback_env(env)
    env['PYTHONUNBUFFERED'] = '1'
    return env
