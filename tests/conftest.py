"""Fixtures shared by every test tier.

The environment: tests need the one `source env.sh` gives (venv, ROS underlay, the
``ros2_ws/install`` overlay). ``make test`` sources it; if pytest was started without it, this
file re-executes pytest once under ``env.sh`` so that ``.venv/bin/pytest tests/...`` works too.

Fixtures
--------
``repo_root``        -> Path of the repository.
``ngsim_loops``      -> factory ``ngsim_loops(stations, closed) -> Dataset``: virtual loops on
                        the shipped NGSIM I-80 part A over 400 m from the real bench's first
                        placement (the trajectories read once per session).
``ros_domain_id``    -> int in 1..100, unique per test among all concurrently running test
                        sessions on this machine (an exclusive ``flock`` per id, released at
                        teardown or when the process dies).
``ros_env``          -> dict: a copy of ``os.environ`` with that ``ROS_DOMAIN_ID``, DDS on
                        loopback only (mlkm_ros.network.loopback_env: the loopback Fast DDS
                        profile, or ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` with
                        ``MLKM_DDS_LOOPBACK=0``), unbuffered Python output; give it to any
                        subprocess you start.
``ros_process``      -> factory ``ros_process(package, executable, *args, env=None,
                        cwd=None) -> Proc`` (mlkm_ros.processes.Proc): starts
                        ``ros2_ws/install/<package>/lib/<package>/<executable>`` in its own
                        process group with ``ros_env`` (``env`` entries are added to it), output
                        to a log file (``.output()``, ``.log_path``). Every process is stopped at
                        teardown, even when the test fails: SIGINT to the group, then SIGTERM,
                        then SIGKILL. ``.stop()`` does that earlier and returns the exit code.
                        Log tails are printed at teardown (pytest shows them on failure).
                        The processes die with this pytest run however it ends (SIGTERM,
                        SIGHUP, Ctrl-C, SIGKILL): see ``_end_children_with_the_run``.
``rclpy_context``    -> a private, initialised ``rclpy.context.Context`` on ``ros_domain_id``
                        (loopback only, no rclpy signal handlers), shut down at teardown
                        after every node made on it is destroyed (so none of its participants
                        outlives the test and reaches a later one in the same domain). Pass
                        it to ``Node(..., context=ctx)`` and ``SingleThreadedExecutor(
                        context=ctx)``.
``spin_until``       -> function ``spin_until(executor, predicate, timeout=10.0) -> bool``:
                        spins ``executor`` in 50 ms steps until ``predicate()`` is true.

Markers (pytest.ini): ``ros`` (starts DDS participants), ``slow``.

Workers: ``make test`` runs two pytest-xdist workers (``-n 2 --dist loadgroup``). The tests
that start the product's executables as processes (tests/graph, tests/bags, and those marked
``ros`` in tests/experiments) form one group, run one after another on one worker, while the
other worker takes the in-process tiers: a graph test shares the machine with one busy core,
as on any loaded machine, never with another graph of nodes. The domain ids of both workers
come from one machine-wide pool (``mlkm_ros.domains.reserve_domain``).
"""

from __future__ import annotations

import atexit
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
INSTALL = REPO_ROOT / 'ros2_ws' / 'install'


def pytest_configure(config: pytest.Config) -> None:
    """Restart this pytest under ``source env.sh`` when the environment is missing (once)."""
    if (
        os.environ.get('MLKM_ROOT')
        or os.environ.get('MLKM_TEST_NO_REEXEC')
        or os.environ.get('PYTEST_XDIST_WORKER')
    ):
        _end_children_with_the_run()
        return
    script = f'source {REPO_ROOT / "env.sh"} >/dev/null && env -0'
    try:
        out = subprocess.run(['bash', '-c', script], check=True, capture_output=True).stdout
    except subprocess.CalledProcessError as exc:
        sys.stderr.write(
            f'conftest: sourcing env.sh failed: {exc.stderr.decode()}\n'
            'run `make setup`, then `source env.sh`\n'
        )
        return
    env = dict(item.split('=', 1) for item in out.decode().split('\0') if '=' in item)
    env['MLKM_TEST_NO_REEXEC'] = '1'
    venv_python = REPO_ROOT / '.venv' / 'bin' / 'python'
    capture = config.pluginmanager.getplugin('capturemanager')
    if capture is not None:  # give the real stdout/stderr back before exec
        capture.stop_global_capturing()
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(str(venv_python), [str(venv_python), *sys.orig_argv[1:]], env)


def _end_children_with_the_run() -> None:
    """However this run ends, the processes its tests started end with it. A Proc (the
    ``ros_process`` fixture, the launcher of demo and replay) dies with this process by
    itself (PR_SET_PDEATHSIG); SIGTERM or SIGHUP (a time limit, a closed terminal) and the
    exit also kill every process group still running and every direct child, whose own Procs
    then die with them. Ctrl-C tears the fixtures down as usual, then the exit does this."""
    from mlkm_ros.processes import kill_all  # after the env.sh re-exec above

    runner = os.getpid()

    def end_all() -> None:
        if os.getpid() != runner:  # a forked child of a test: the groups are not its own
            return
        kill_all()
        for pid in _children(os.getpid()):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass

    def on_signal(signum: int, _frame: object) -> None:
        end_all()  # in a forked child: nothing, then the signal's default action
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)  # end as that signal asks

    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, on_signal)
    atexit.register(end_all)


def _children(pid: int) -> list[int]:
    """Direct children of ``pid`` (Linux /proc)."""
    out = []
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


#: tiers whose tests start the product's executables as separate processes
_PROCESS_TIERS = ('graph', 'bags')


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The tests that start node processes into one xdist group (see Workers above). First
    among the hooks: xdist's worker turns the group marks into a suffix of each test's id in
    its own hook of this name, and a mark added after it would be ignored."""
    for item in items:
        parts = Path(item.path).relative_to(REPO_ROOT / 'tests').parts
        tier = parts[0] if len(parts) > 1 else ''
        if tier in _PROCESS_TIERS or (tier == 'experiments' and item.get_closest_marker('ros')):
            item.add_marker(pytest.mark.xdist_group('processes'))


def pytest_xdist_node_collection_finished(node, ids: list[str]) -> None:
    """On the xdist controller with ``--dist loadgroup``: stop when the group did not take (a
    node-process test's id lacks the group's suffix), rather than spread those tests over both
    workers unnoticed. pytest 9.2 with xdist 3.8 drops the suffix (pytest-xdist#1386), hence
    the pin in requirements.txt."""
    if node.config.getvalue('dist') != 'loadgroup':
        return
    lost = [i for i in ids if i.startswith(('tests/graph/', 'tests/bags/')) and '@' not in i]
    if lost:
        raise pytest.UsageError(
            f'--dist loadgroup: {len(lost)} node-process tests lost their xdist group (first: '
            f'{lost[0]}); this pytest and pytest-xdist do not group tests (pytest-xdist#1386)'
        )


@pytest.fixture(scope='session')
def repo_root() -> Path:
    return REPO_ROOT


@pytest.fixture(scope='session')
def ngsim_loops(repo_root):
    import numpy as np

    from mlkm_core.loops import even_positions, virtual_loops
    from mlkm_core.trajectories import read_trajectories

    traj = read_trajectories(repo_root / 'data' / 'ngsim_i80' / 'i80_trajectories_a.csv.gz')
    # the first station of the real bench's first placement (``bench.real.placement(1)``)
    x0 = float(np.random.default_rng(1).uniform(20.0, 100.0))

    def loops(stations: int, closed: bool):
        return virtual_loops(traj, even_positions(stations, x0, x0 + 400.0), closed).dataset

    return loops


@pytest.fixture
def ros_domain_id() -> Iterator[int]:
    """A ROS_DOMAIN_ID that no other test, demo or session on this machine holds right now."""
    from mlkm_ros.domains import reserve_domain  # after the env.sh re-exec above

    with reserve_domain() as domain_id:
        yield domain_id


@pytest.fixture
def ros_env(ros_domain_id: int) -> dict[str, str]:
    """Environment for subprocesses: own domain, DDS on loopback only, the overlay."""
    from mlkm_ros.network import loopback_active, loopback_env  # after the env.sh re-exec

    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(ros_domain_id)
    if not loopback_active(env):
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.pop('ROS_LOCALHOST_ONLY', None)  # deprecated in Jazzy; conflicts with the above
    env.pop('ROS_STATIC_PEERS', None)
    loopback_env(env)  # the loopback-only Fast DDS profile, unless MLKM_DDS_LOOPBACK=0
    env['PYTHONUNBUFFERED'] = '1'
    return env


def executable_path(package: str, executable: str) -> Path:
    """``ros2_ws/install/<package>/lib/<package>/<executable>``, as ``ros2 run`` finds it."""
    path = INSTALL / package / 'lib' / package / executable
    if not os.access(path, os.X_OK):
        have = sorted(p.name for p in path.parent.glob('*')) if path.parent.is_dir() else []
        pytest.fail(
            f'no executable {executable!r} in package {package!r} ({path}); '
            f'installed: {have or "nothing (run make setup)"}'
        )
    return path


@pytest.fixture
def ros_process(ros_env: dict[str, str], tmp_path: Path) -> Iterator[Callable[..., object]]:
    from mlkm_ros.processes import Proc  # after the env.sh re-exec above

    started: list[Proc] = []

    def start(
        package: str,
        executable: str,
        *args: str,
        env: dict[str, str] | None = None,
        cwd: Path | None = None,
    ) -> Proc:
        argv = [str(executable_path(package, executable)), *map(str, args)]
        log_path = tmp_path / f'{executable}-{len(started)}.log'
        proc = Proc(
            f'{package}/{executable}', argv, {**ros_env, **(env or {})}, log_path,
            cwd=cwd or tmp_path,
        )  # fmt: skip
        started.append(proc)
        return proc

    yield start
    for proc in reversed(started):
        code = proc.stop(5.0)
        tail = '\n'.join(proc.output().splitlines()[-30:])
        print(f'--- {proc.name} (pid {proc.pid}, exit {code}), end of {proc.log_path}:\n{tail}')


@pytest.fixture
def rclpy_context(ros_domain_id: int, monkeypatch: pytest.MonkeyPatch):
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    from mlkm_ros.network import loopback_env

    # The RMW reads these when the context is initialised.
    net = loopback_env({**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'})
    for name in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'FASTRTPS_DEFAULT_PROFILES_FILE'):
        if name in net:
            monkeypatch.setenv(name, net[name])
    monkeypatch.setenv('ROS_DOMAIN_ID', str(ros_domain_id))
    monkeypatch.delenv('ROS_LOCALHOST_ONLY', raising=False)
    ctx = Context()
    rclpy.init(
        context=ctx, domain_id=ros_domain_id, signal_handler_options=SignalHandlerOptions.NO
    )
    nodes = _nodes_made_in(ctx, monkeypatch)
    try:
        yield ctx
    finally:
        # A shut-down context's DDS participant lives on while any of its nodes is referenced
        # (a thread, a closure) and keeps serving its latched messages; a later test that draws
        # the same domain id would receive them. Destroying the nodes ends the participant.
        for ref in nodes:
            node = ref()
            if node is not None:
                try:
                    node.destroy_node()
                except Exception:  # noqa: BLE001 - already destroyed, or its context is gone
                    pass
        rclpy.try_shutdown(context=ctx)


def _nodes_made_in(ctx, monkeypatch: pytest.MonkeyPatch) -> list:
    """Weak references to every rclpy Node created on ``ctx`` from now on."""
    import weakref

    from rclpy.node import Node

    made: list = []
    original = Node.__init__

    def init(self, *args, **kwargs) -> None:
        original(self, *args, **kwargs)
        if self.context is ctx:
            made.append(weakref.ref(self))

    monkeypatch.setattr(Node, '__init__', init)
    return made


def _spin_until(executor, predicate: Callable[[], bool], timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() >= deadline:
            return False
        executor.spin_once(timeout_sec=0.05)
    return True


@pytest.fixture
def spin_until() -> Callable[..., bool]:
    return _spin_until
