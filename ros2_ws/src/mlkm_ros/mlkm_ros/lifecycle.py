"""How a node's process starts and ends: Ctrl-C or SIGTERM at any moment (during the imports,
the node's construction, its work or its clean-up) ends it with exit status 0 and no
traceback, and its helper processes die with it.

rclpy's own signal handlers shut the context down from another thread and then raise
KeyboardInterrupt in the main thread, so a signal could land while the executor builds its
wait set (``RCLError: ... context is not valid``) or in the middle of the clean-up. Here a
signal only sets a flag (:data:`STOP`); the main thread spins the node in short steps
(:func:`spin`), sees the flag, leaves the loop and cleans up in order. The installed
executables start through :func:`run`, which catches the signals before the node's module
(and rclpy, numpy, ...) is imported (:func:`entry_point`), and a node's ``main`` is
:func:`run_node`, or :func:`start_node` where the node ends its run itself.

This module imports no rclpy at module level: the helper processes of a node use
:func:`die_with_parent` without loading ROS.
"""

from __future__ import annotations

import ctypes
import importlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

#: How a node's ``main`` answers an exception of its construction: (the exception types, the
#: text put between the executable's name and the exception's, the exit status).
Refusal = tuple[tuple[type[BaseException], ...], str, int]
#: Exit status of a refused parameter value.
EXIT_BAD_PARAMETER = 2

#: The signals that end a node: Ctrl-C and a polite kill.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: How long one executor step waits for work [s]: the longest a stop waits to be seen.
SPIN_STEP = 0.1
PR_SET_PDEATHSIG = 1  # linux/prctl.h


class StopRequest:
    """Set by SIGINT or SIGTERM (or :meth:`request`); one per process."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self.signum: int | None = None
        self._signalled = False

    @property
    def requested(self) -> bool:
        return self._event.is_set()

    def request(self, signum: int | None = None) -> None:
        if self.signum is None:
            self.signum = signum
        self._event.set()

    def wait(self, timeout: float | None = None) -> bool:
        return self._event.wait(timeout)

    def clear(self) -> None:
        self.signum = None
        self._signalled = False
        self._event.clear()

    def handler(self, signum: int, _frame: Any) -> None:
        """The signal handler. Python runs it in the main thread between two bytecodes, also
        inside an earlier run of itself: a second signal while the first one holds the
        event's lock would wait for that lock forever, one nested handler per further
        signal, until the recursion limit. Only the first signal sets the event."""
        if self._signalled:
            return
        self._signalled = True
        self.request(signum)


#: The process's stop request.
STOP = StopRequest()


@contextmanager
def stop_signals() -> Iterator[StopRequest]:
    """SIGINT and SIGTERM set :data:`STOP` while inside; the previous handlers come back on
    leaving (a node's ``main`` called in process, by a test, leaves pytest's Ctrl-C alone).
    Outside the main thread no handler can be installed: the flag is still returned."""
    if threading.current_thread() is not threading.main_thread():
        yield STOP
        return
    previous = {sig: signal.signal(sig, STOP.handler) for sig in STOP_SIGNALS}
    try:
        yield STOP
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def run(module: str, args: list[str] | None = None) -> int:
    """Entry point of an installed executable: import ``module`` and return its
    ``main(args)``. A stop signal during the import ends the process at once with exit 0
    (SystemExit: nothing is running yet); from then on it only sets :data:`STOP`, and once
    ``main`` has returned it is ignored: the interpreter's shut-down puts the default
    handlers back, and a second Ctrl-C (``ros2 launch`` forwards the terminal's) would kill
    the process with -SIGINT after it decided its exit status."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, _exit_quietly)
    try:
        main: Callable[[list[str] | None], int] = importlib.import_module(module).main
    finally:
        for sig in STOP_SIGNALS:
            signal.signal(sig, STOP.handler)
    try:
        return main(args)
    finally:
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.SIG_IGN)


def entry_point(module: str) -> Callable[[], int]:
    """The console-script function of the executable whose node lives in ``module``: it
    starts through :func:`run` (setup.py names these functions in the packages' entry.py)."""

    def start() -> int:
        return run(module)

    start.__name__ = start.__qualname__ = module.rsplit('.', 1)[-1]
    start.__doc__ = f'Run ``{module}.main`` with the stop signals caught from the start.'
    return start


def _exit_quietly(_signum: int, _frame: Any) -> None:
    raise SystemExit(0)


def init_rclpy(args: list[str] | None) -> None:
    """``rclpy.init`` without rclpy's signal handlers (see the module docstring)."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)


def parameter_refusal() -> Refusal:
    """A refused parameter value: ``<name>: <reason>`` and exit status 2."""
    from mlkm_ros.params import ParameterError

    return (ParameterError,), '', EXIT_BAD_PARAMETER


def start_node[NodeT](
    name: str, factory: Callable[[], NodeT], refusals: Sequence[Refusal]
) -> tuple[NodeT | None, int]:
    """Construct a node (after :func:`init_rclpy`): (the node, 0), or, when the constructor
    raises one of ``refusals``' exceptions, (None, its exit status) after printing
    ``<name>: <text><exception>`` to stderr and shutting rclpy down. A refusal raised after a
    stop was requested is the stop's own doing (Ctrl-C reaches the whole process group, so a
    helper the constructor runs, such as SUMO's netconvert, dies of it first): (None, 0),
    with a note of what was cut short."""
    import rclpy

    try:
        return factory(), 0
    except BaseException as exc:
        for types, text, status in refusals:
            if isinstance(exc, types):
                if STOP.requested:
                    print(f'{name}: stopped during start-up ({exc})', file=sys.stderr)
                    status = 0
                else:
                    print(f'{name}: {text}{exc}', file=sys.stderr)
                rclpy.try_shutdown()
                return None, status
        raise


def run_node(
    name: str,
    factory: Callable[[], Any],
    args: list[str] | None,
    *,
    refusals: Sequence[Refusal] = (),
    before_init: Callable[[], None] | None = None,
    drop_helpers: bool = False,
    finish: Callable[[Any], int] | None = None,
) -> int:
    """A node's ``main``: init, construct (a refused parameter, or one of ``refusals``, ends
    it with that exit status), spin until stopped, destroy, shut down; 0 once it ran.
    ``before_init`` runs first (helper processes forked before any ROS thread);
    ``drop_helpers``: after Ctrl-C the helper processes are killed, not waited for;
    ``finish(node)``, after the spin and before the node is destroyed, returns the exit status
    of a node that ends its run itself (0 without it)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException

    # Ctrl-C and SIGTERM only end the spin (see the module docstring): exit 0, no traceback
    with stop_signals():
        if before_init is not None:
            before_init()
        init_rclpy(args)
        node, status = start_node(name, factory, [*refusals, parameter_refusal()])
        if node is None:
            return status
        try:
            spin(node)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            if drop_helpers and STOP.requested:
                end_helpers()  # the work in hand is not waited for
            status = 0 if finish is None else finish(node)
            node.destroy_node()
            rclpy.try_shutdown()
    return status


def spin(node: Any, until: Callable[[], bool] | None = None) -> None:
    """Spin ``node`` in the calling thread until a stop was requested, ``until()`` holds or
    its context was shut down (by the node itself, for example at the end of its run)."""
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    context = node.context
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        while not STOP.requested and context.ok() and not (until is not None and until()):
            executor.spin_once(timeout_sec=SPIN_STEP)
    except ExternalShutdownException:
        pass
    except RCLError:
        if context.ok():
            raise  # a context shut down while the wait set was built is an end, not an error
    finally:
        executor.remove_node(node)
        executor.shutdown(timeout_sec=0.0)


def end_helpers(timeout: float = 2.0) -> None:
    """After a stop request: kill the process's helper processes (multiprocessing children)
    and reap them. A Ctrl-C drops the work they have in hand instead of waiting for it (a
    helper still importing would not even take SIGTERM before it is up); the node's own
    clean-up then finds them gone."""
    import multiprocessing

    children = multiprocessing.active_children()
    for child in children:
        child.kill()
    deadline = time.monotonic() + timeout
    for child in children:
        child.join(max(0.0, deadline - time.monotonic()))


def die_with_parent(parent: int | None = None) -> None:
    """In a helper process: be killed (SIGKILL) when the thread that started it ends, which
    for a node's helpers is the node's main thread, so they never outlive a node that was
    killed. Exits at once when ``parent`` (the expected parent pid) is already gone."""
    if sys.platform.startswith('linux'):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if parent is not None and os.getppid() != parent:
        os._exit(0)


def pdeathsig_preexec() -> Callable[[], None] | None:
    """A ``preexec_fn`` for ``subprocess.Popen`` that makes the child die (SIGKILL) with the
    thread that starts it; None off Linux. The libc function is looked up here, in the
    parent, so that the child only makes the system call between fork and exec."""
    if not sys.platform.startswith('linux'):
        return None
    prctl = ctypes.CDLL(None, use_errno=True).prctl
    kill = int(signal.SIGKILL)

    def preexec() -> None:
        prctl(PR_SET_PDEATHSIG, kill, 0, 0, 0)

    return preexec


@contextmanager
def stop_signals_blocked() -> Iterator[None]:
    """Block SIGINT and SIGTERM in the calling thread while it starts a helper process, which
    inherits the mask: a Ctrl-C to the process group during the helper's imports is then no
    traceback, and :func:`helper_process` unblocks them once the helper ignores Ctrl-C. A
    signal that reaches the caller meanwhile is delivered on leaving."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def start_helper(ctx: Any, target: Callable[..., None], args: tuple, name: str) -> Any:
    """Start a daemon helper process of the node from the multiprocessing context ``ctx``,
    with the stop signals blocked while it starts (:func:`stop_signals_blocked`); ``target``
    calls :func:`helper_process` first. Returns the started process."""
    proc = ctx.Process(target=target, args=args, name=name, daemon=True)
    with stop_signals_blocked():
        proc.start()
    return proc


def helper_process(parent: int) -> None:
    """First thing in a node's helper process (started under :func:`stop_signals_blocked`):
    ignore Ctrl-C (the node stops its helpers itself), end on SIGTERM, die with the node's
    process ``parent`` even when it is killed (:func:`die_with_parent`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    die_with_parent(parent)
