"""Helpers for everything that runs the node graph: demo, replay, benchmarks and the tests.

They start the installed executables as separate processes, exactly as a user would with
``ros2 run`` in separate terminals, on loopback DDS and a ROS domain of their own
(``mlkm_ros.domains``), and stop every one of them (SIGINT, then SIGTERM, then SIGKILL)
whatever happens.

Part of the product (the demo, the replay and the tests use it; the benchmarks in
mlkm_experiments import it from here). Importing it loads no rclpy: only
:class:`ScoreCollector` and :func:`executable` import ROS modules, when called.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from mlkm_ros.domains import graph_env

#: Every Proc started by this process and not yet stopped, by process group id.
_RUNNING: dict[int, Proc] = {}


def executable(package: str, name: str) -> Path:
    """``<prefix of package>/lib/<package>/<name>``, as ``ros2 run`` finds it."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        prefix = Path(get_package_prefix(package))
    except PackageNotFoundError:
        raise RuntimeError(
            f'package {package!r} not found; run `make setup` and `source env.sh`'
        ) from None
    path = prefix / 'lib' / package / name
    if not os.access(path, os.X_OK):
        raise RuntimeError(f'no executable {name!r} in package {package!r} ({path})')
    return path


class Proc:
    """One started executable, in its own process group, output to a log file.

    It dies with the thread that starts it (SIGKILL, ``PR_SET_PDEATHSIG``), so a killed
    demo, benchmark or test run leaves no node behind; start it from a thread that outlives
    it (the main thread). :func:`kill_all` ends every group still running."""

    def __init__(
        self,
        name: str,
        argv: list[str],
        env: dict[str, str],
        log_path: Path,
        echo: bool = False,
        cwd: Path | None = None,
    ) -> None:
        self.name = name
        self.argv = argv
        self.log_path = log_path
        log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(log_path, 'wb') as log:
            self.proc = subprocess.Popen(
                argv,
                env=env,
                cwd=cwd,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                preexec_fn=_PDEATHSIG,
            )
        _RUNNING[self.proc.pid] = self
        if echo:
            print(f'started {name} (pid {self.proc.pid}): {" ".join(argv)}', flush=True)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def poll(self) -> int | None:
        return self.proc.poll()

    def output(self) -> str:
        try:
            return self.log_path.read_text(errors='replace')
        except FileNotFoundError:
            return ''

    def wait_for_output(self, text: str, timeout: float = 10.0) -> bool:
        """Wait until ``text`` appears in the output; False on timeout or early exit."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.output():
                return True
            if self.proc.poll() is not None:
                return text in self.output()
            time.sleep(0.05)
        return False

    def wait(self, timeout: float) -> int | None:
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return None

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Wait until the process is idle; see :func:`wait_idle`."""
        return wait_idle(self.proc.pid, timeout)

    def stop(self, grace: float = 10.0) -> int:
        """SIGINT (as Ctrl-C), then SIGTERM, then SIGKILL, to the process group; whatever
        is left of the group after the leader exited is killed too."""
        status = stop_process_group(self.proc, grace)
        _killpg(self.proc.pid, signal.SIGKILL)
        _RUNNING.pop(self.proc.pid, None)
        return status


def kill_all() -> list[str]:
    """SIGKILL every process group a Proc of this process started and did not stop yet (a
    run interrupted by SIGTERM or Ctrl-C); returns their names. Safe in a signal handler or
    at exit."""
    names = []
    for pgid, proc in list(_RUNNING.items()):
        _killpg(pgid, signal.SIGKILL)
        names.append(proc.name)
        _RUNNING.pop(pgid, None)
    return names


def _pdeathsig():
    from mlkm_ros.lifecycle import pdeathsig_preexec

    return pdeathsig_preexec()


_PDEATHSIG = _pdeathsig()


def stop_process_group(proc: subprocess.Popen, grace: float = 10.0) -> int:
    """Stop a process started in its own group: SIGINT (as Ctrl-C) and ``grace`` seconds,
    then SIGTERM and 3 s, then SIGKILL. Returns its exit status."""
    for sig, wait in ((signal.SIGINT, grace), (signal.SIGTERM, 3.0)):
        if proc.poll() is not None:
            break
        _killpg(proc.pid, sig)
        try:
            proc.wait(wait)
        except subprocess.TimeoutExpired:
            pass
    if proc.poll() is None:
        _killpg(proc.pid, signal.SIGKILL)
        proc.wait(5.0)
    return proc.returncode


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU time process ``pid`` used so far [s] (Linux /proc); None if gone."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except (FileNotFoundError, IndexError, ProcessLookupError):
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def wait_idle(
    pid: int,
    timeout: float = 60.0,
    period: float = 0.25,
    quiet: int = 4,
    busy_fraction: float = 0.1,
) -> bool:
    """Wait until process ``pid`` is idle (CPU below ``busy_fraction`` for ``quiet``
    periods in a row), e.g. a recorder that has worked off the messages DDS already
    delivered to it. False on timeout or when the process is gone."""
    deadline = time.monotonic() + timeout
    last, calm = cpu_seconds(pid), 0
    while last is not None and time.monotonic() < deadline:
        time.sleep(period)
        now = cpu_seconds(pid)
        if now is None:
            return False
        calm = calm + 1 if now - last < busy_fraction * period else 0
        last = now
        if calm >= quiet:
            return True
    return False


def _killpg(pgid: int, sig: int) -> None:
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        pass


class Graph:
    """Starts named processes and stops them all (reverse order) on exit."""

    def __init__(self, domain_id: int, log_dir: Path, echo: bool = True) -> None:
        self.env = graph_env(domain_id)
        self.log_dir = log_dir
        self.echo = echo
        self.procs: dict[str, Proc] = {}

    def start(self, name: str, package: str, exe: str, *args: str) -> Proc:
        argv = [str(executable(package, exe)), *args]
        proc = Proc(name, argv, self.env, self.log_dir / f'{name}.log', self.echo)
        self.procs[name] = proc
        return proc

    def start_argv(self, name: str, *argv: str) -> Proc:
        proc = Proc(name, list(argv), self.env, self.log_dir / f'{name}.log', self.echo)
        self.procs[name] = proc
        return proc

    def stop(self, name: str, grace: float = 10.0) -> int:
        return self.procs[name].stop(grace)

    def stop_all(self) -> dict[str, int]:
        return {name: p.stop() for name, p in reversed(list(self.procs.items()))}

    def close_recorder(self, label: str, name: str = 'bag_recorder') -> None:
        """Stop the recorder ``name`` once it is idle (it takes what DDS already acknowledged
        at its own pace; after 60 s busy it is stopped anyway) with SIGINT, so that it closes
        the bag cleanly; RuntimeError when it exits nonzero."""
        proc = self.procs[name]
        if not proc.wait_idle(timeout=60.0):
            print(
                f'{label}: the recorder stayed busy for 60 s; stopping it anyway', file=sys.stderr
            )
        code = self.stop(name, grace=20.0)
        if code != 0:
            raise RuntimeError(f'{name} exited with {code}; log {proc.log_path}')

    def report_failure(self, label: str, exc: BaseException) -> int:
        """Stop every process and print why the run failed with the last lines of each
        process's output; returns the exit status of a failed run (1)."""
        self.stop_all()
        print(f'{label}: FAILED: {exc}', file=sys.stderr)
        for proc in self.procs.values():
            tail = '\n    '.join(proc.output().splitlines()[-8:])
            print(f'--- {proc.name} (exit {proc.poll()}):\n    {tail}', file=sys.stderr)
        return 1

    def failed(self, ignore: tuple[str, ...] = ()) -> str | None:
        """Name and exit code of a process that exited nonzero, if any."""
        for name, p in self.procs.items():
            code = p.poll()
            if name not in ignore and code not in (None, 0):
                return f'{name} exited with code {code}; log {p.log_path}'
        return None

    def __enter__(self) -> Graph:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_all()


def recorder_args(bag_dir: Path) -> list[str]:
    """The bag_recorder's arguments: every topic of the graph into ``bag_dir`` but the ROS
    housekeeping ones."""
    from mlkm_ros.qos import RECORD_EXCLUDE_REGEX  # rclpy's QoS: not needed by the rest

    return [
        '--ros-args',
        '-p',
        f'output:={bag_dir}',
        '-p',
        f'exclude_regex:={RECORD_EXCLUDE_REGEX}',
    ]


def start_association(
    graph: Graph,
    collector: ScoreCollector,
    method: str,
    *also: tuple[str, ...],
    association_params: tuple[str, ...] = (),
    scorer_params: tuple[str, ...] = (),
    timeout: float = 30.0,
) -> None:
    """Start association_node and scorer_node, then ``also`` (each ``(name, package, exe,
    *args)``), and wait until /mlkm/tracks is matched by the scorer and each of ``also``, so
    that no track update is published before its subscribers are there.

    ``association_params`` / ``scorer_params`` are further ``name:=value`` parameters (stream
    mode, for example)."""
    assoc = (f'method:={method}', *association_params)
    graph.start('association_node', 'mlkm_assoc', 'association_node', *_ros_params(assoc))
    graph.start('scorer_node', 'mlkm_assoc', 'scorer_node', *_ros_params(scorer_params))
    for spec in also:
        graph.start(*spec)
    node = collector.node
    why = collector.spin_until(
        lambda: (
            node.count_publishers('/mlkm/tracks') >= 1
            and node.count_subscribers('/mlkm/tracks') >= 1 + len(also)
        ),
        timeout=timeout,
        abort=graph.failed,
    )
    if why:
        raise RuntimeError(f'graph did not come up: {why}')


def _ros_params(params: tuple[str, ...]) -> list[str]:
    """``--ros-args -p a:=1 -p b:=2`` for ('a:=1', 'b:=2'); nothing for no parameters."""
    return ['--ros-args', *(arg for p in params for arg in ('-p', p))] if params else []


class ScoreCollector:
    """An in-process subscriber to /mlkm/score (and optionally /diagnostics) on a private
    context; ``wait_for(n)`` spins until n episodes were scored."""

    def __init__(self, domain_id: int, diagnostics: bool = False) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.signals import SignalHandlerOptions

        from mlkm_ros import qos
        from road_sensor_msgs.msg import AssociationScore

        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        self._rclpy = rclpy
        self.context = Context()
        rclpy.init(
            context=self.context,
            domain_id=domain_id,
            signal_handler_options=SignalHandlerOptions.NO,
        )
        self.node = Node('score_collector', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.scores: dict[int, AssociationScore] = {}
        self.diagnostics: list[DiagnosticArray] = []
        self.node.create_subscription(
            AssociationScore, qos.SCORE_TOPIC, self._on_score, qos.SCORE_QOS
        )
        if diagnostics:
            self.node.create_subscription(
                DiagnosticArray,
                qos.DIAGNOSTICS_TOPIC,
                self.diagnostics.append,
                qos.DIAGNOSTICS_QOS,
            )

    def _on_score(self, msg) -> None:
        self.scores[msg.episode_id] = msg

    def spin_until(
        self,
        predicate: Callable[[], bool],
        timeout: float,
        abort: Callable[[], str | None] = lambda: None,
    ) -> str | None:
        """Spin until ``predicate()``; returns None, or why it stopped early."""
        deadline = time.monotonic() + timeout
        while not predicate():
            why = abort()
            if why:
                return why
            if time.monotonic() > deadline:
                return f'timed out after {timeout:g} s'
            self.executor.spin_once(timeout_sec=0.05)
        return None

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)


def replay_hint(bag_dir: Path, root: Path) -> str:
    """The line a demo ends with: where its bag is and how to replay it (the path relative to
    ``root``, the repository, where it lies inside)."""
    try:
        rel = str(bag_dir.relative_to(root))
    except ValueError:
        rel = str(bag_dir)
    return f'bag: {bag_dir}  (replay: make replay BAG={rel})'


def format_scores(scores: dict, title: str) -> str:
    """Per-episode accuracy and the mean, as printed by the demo and the replay."""
    lines = [title, 'episode  method      accuracy  correct/total  link P / R        ARI']
    for e in sorted(scores):
        s = scores[e]
        lines.append(
            f'{e:7d}  {s.method:10s}  {s.accuracy:8.4f}  {s.correct:6d}/{s.total:<6d}'
            f'  {s.link_precision:.4f}/{s.link_recall:.4f}  '
            f'{s.adjusted_rand_index:.4f}'
        )
    if scores:
        mean = sum(s.accuracy for s in scores.values()) / len(scores)
        lines.append(f'mean accuracy over {len(scores)} episode(s): {mean:.4f}')
    return '\n'.join(lines)
