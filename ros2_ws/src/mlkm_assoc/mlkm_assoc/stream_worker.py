"""Stream mode's tracker process: :class:`~mlkm_assoc.stream_state.TrackerState` (the
core's :class:`~mlkm_core.streaming.StreamTracker`) in a process of its own, fed detection by
detection, answering with ready-to-publish TrackArrays.

The node's executor thread only validates a detection and queues it (fast ingest; a sender
thread writes what queued up as one list); this process puts it through the reorder buffer
(:mod:`mlkm_assoc.reorder`, which undoes the round-robin over the sensor topics) into the
tracker, which links it at once. The tracker's window solves run in a third process
(:mod:`mlkm_assoc.stream_solver`): a push only submits a due window, and the solution is
applied at its boundary when it is done (polled after every batch and every few
milliseconds while a solve is in flight), so no detection waits for a solve and the commits
flow while the road is quiet. With the tracker's own reorder tolerance, the committed labels
are a function of the detections alone, so live equals ``mlkm associate --stream`` on the
same detections.

Start-up. A spawned process pays seconds of imports (scikit-learn, SciPy) before it can take
a detection, tens of seconds on a busy machine. So the node's ``main`` calls ``prestart``
before ``rclpy.init``, while it runs no ROS thread: the tracker and solver processes are
forked from it then, with everything imported, and wait for their settings; stream mode takes
them and they are ready within a fraction of a second. Without a prestarted pair (a node
built in a test process) they are spawned. Either way the node subscribes at once: the
detections queue for the process (at most ``max_queued``; beyond, they are refused and
counted) and none is lost while it starts.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from mlkm_assoc.stream_shard import encode_handoff
from mlkm_assoc.stream_solver import SolverClient, SolverProcess
from mlkm_assoc.stream_state import (
    NS_PER_S,
    Answer,
    Item,
    TrackerSettings,
    TrackerState,
    encode_tracks,
)
from mlkm_core.types import Layout
from mlkm_ros.lifecycle import helper_process, start_helper

#: Queued items (detections and ticks) taken as one batch at most [-].
MAX_BATCH = 512
#: Wait for queued items while a window solve is in flight [s]: how often it is polled.
POLL_PERIOD = 0.005
#: Sent by the tracker process once it has warmed up, before any Answer.
READY = 'ready'


class _Processes:
    """A tracker process and its solver process, started; the tracker waits for its
    settings (the first item)."""

    def __init__(self, ctx) -> None:
        self.solver = SolverProcess(ctx)
        items, self.item_sender = ctx.Pipe(duplex=False)
        self.answers, sender = ctx.Pipe(duplex=False)
        # a forked child inherits every descriptor: it closes the node's ends of its pipes
        inherited = (self.item_sender, self.answers) if ctx.get_start_method() == 'fork' else ()
        self.proc = start_helper(
            ctx,
            _serve,
            (items, sender, os.getpid(), self.solver.ends, inherited),
            'mlkm_stream_tracker',
        )
        sender.close()
        items.close()


#: The processes forked by ``prestart``, for the first TrackerProcess.
_PRESTARTED: list[_Processes] = []


def prestart() -> None:
    """Fork a tracker process and its solver process now, to be taken by the first
    TrackerProcess. Call it before ``rclpy.init`` (no ROS threads yet): the children get every
    module the node imported, so they are ready at once instead of importing for seconds."""
    import scipy.optimize  # noqa: F401  (the linking and calibration import it on first use)

    import mlkm_core.streaming  # noqa: F401  (the tracker and the solves need them)
    import mlkm_core.streaming.solve  # noqa: F401
    from mlkm_ros import conversions  # noqa: F401  (encode_tracks)

    if not _PRESTARTED and threading.active_count() == 1:  # never fork a running thread's state
        _PRESTARTED.append(_Processes(multiprocessing.get_context('fork')))


def discard_prestarted() -> None:
    """Stop the prestarted processes (the node does not run stream mode)."""
    while _PRESTARTED:
        parts = _PRESTARTED.pop()
        try:
            parts.item_sender.send([None])
        except OSError:
            pass
        parts.proc.join(5.0)
        if parts.proc.is_alive():
            parts.proc.terminate()
            parts.proc.join(2.0)
        parts.item_sender.close()
        parts.solver.close()


class TrackerProcess:
    """The tracker process: items go in with ``put``; ``get`` returns each Answer (None once
    the process ended). At most ``max_queued`` detections (0: no limit) wait for the process;
    ``put`` refuses more. ``on_ready(seconds)`` is called from the thread that calls ``get``
    once the process is ready, with the time since this object was made."""

    def __init__(
        self,
        settings: TrackerSettings,
        max_queued: int = 0,
        on_ready: Callable[[float], None] | None = None,
    ) -> None:
        self._ready = threading.Event()
        self._on_ready = on_ready
        self._started_at = time.monotonic()
        parts = _PRESTARTED.pop() if _PRESTARTED else None
        self.forked = parts is not None  # taken from ``prestart``
        if parts is None:
            parts = _Processes(multiprocessing.get_context('spawn'))
        self._solver, self._proc, self._answers = parts.solver, parts.proc, parts.answers
        self._items = _BatchSender(parts.item_sender, max_queued)
        self._items.put(('settings', settings))

    @property
    def ready(self) -> bool:
        return self._ready.is_set()

    @property
    def queued(self) -> int:
        """Items waiting in the node for the process (not yet written to its pipe)."""
        return self._items.queued

    def put(self, item: Item | None) -> bool:
        """Queue an item; False, and nothing queued, for a detection beyond ``max_queued``."""
        return self._items.put(item)

    def get(self, timeout: float | None = None) -> Answer | None:
        """The next Answer (None once the process ended); TimeoutError after ``timeout``."""
        while True:
            try:
                if timeout is not None and not self._answers.poll(timeout):
                    raise TimeoutError(f'no answer from the tracker process in {timeout:g} s')
                answer = self._answers.recv()
            except (EOFError, OSError):
                self._ready.set()  # nobody waits for a process that is gone
                return None
            if answer != READY:
                return answer
            self._ready.set()
            if self._on_ready is not None:
                self._on_ready(time.monotonic() - self._started_at)

    def wait_ready(self, timeout: float) -> bool:
        """Wait until the process has warmed up (needs a reader calling ``get``); False if it
        did not within ``timeout`` seconds."""
        return self._ready.wait(timeout)

    def close(self, timeout: float = 5.0) -> None:
        self._items.put(None)  # also ends the sender thread of a process already gone
        if self._proc.is_alive():
            self._proc.join(timeout)
        self._items.close()
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(2.0)
        self._solver.close()


class _BatchSender:
    """Items to the tracker process from a thread of its own, as lists: whatever queued up
    while the last list was written goes in the next one (one pickle and one write per list,
    not per detection; one item per list while the rate is low). While the process does not
    take them (it is starting, or behind), at most ``limit`` items wait here (0: no limit):
    beyond, detections and clock ticks are refused; layouts, flushes and the stop never are."""

    def __init__(self, conn, limit: int = 0) -> None:
        self._conn = conn
        self._limit = limit
        self._items: deque[Item | None] = deque()
        self._wake = threading.Event()
        self._thread = threading.Thread(target=self._run, name='stream_sender', daemon=True)
        self._thread.start()

    @property
    def queued(self) -> int:
        return len(self._items)

    def put(self, item: Item | None) -> bool:
        if (
            self._limit
            and len(self._items) >= self._limit
            and item is not None
            and item[0] in ('det', 'tick')
        ):
            return False
        self._items.append(item)
        self._wake.set()
        return True

    def _run(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()
            batch = []
            while self._items:
                batch.append(self._items.popleft())
            if not batch:
                continue
            try:
                self._conn.send(batch)
            except (BrokenPipeError, OSError):
                return  # the tracker process is gone
            if None in batch:
                return

    def close(self) -> None:
        self._thread.join(timeout=5.0)
        self._conn.close()


def _serve(items, answers, parent: int, solver_ends=None, inherited=()) -> None:
    """Process main loop: the settings first, then lists of items in, detections through the
    reorder buffer into the tracker, one Answer per batch of at most MAX_BATCH items out.
    ``inherited``: the node's ends of the pipes, which a forked child holds too."""
    helper_process(parent)  # Ctrl-C is for the node, which stops us; we die with it
    for conn in inherited:
        conn.close()
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:
        pass
    pending: deque[Item | None] = deque()
    try:
        while not pending:
            if items.poll(1.0):
                pending.extend(items.recv())
            elif os.getppid() != parent:
                return
    except (EOFError, OSError):
        return  # the node is gone
    first = pending.popleft()
    if first is None or first[0] != 'settings':
        return  # stopped before it was used
    settings: TrackerSettings = first[1]
    _warm_up(settings)
    executor = SolverClient(solver_ends) if solver_ends is not None else None
    state = TrackerState(settings, encode_tracks, executor, encode_handoff)
    answers.send(READY)
    while True:
        try:
            if not pending:
                if not items.poll(POLL_PERIOD if state.solving else 1.0):
                    if os.getppid() != parent:
                        return
                    state.defer_solves(False)
                    _send(answers, state.poll())
                    continue
                pending.extend(items.recv())
            while len(pending) <= MAX_BATCH and items.poll(0):
                pending.extend(items.recv())
        except (EOFError, OSError):
            return  # the node is gone
        # more than a batch waiting: the node is delivering a backlog; the window solves
        # wait until it is taken (they would take the CPU the node needs to receive it)
        state.defer_solves(len(pending) > MAX_BATCH)
        for _ in range(min(MAX_BATCH, len(pending))):
            item = pending.popleft()
            if item is None:
                _send(answers, state.release(drain=True))
                answers.send(None)
                answers.close()
                return
            if item[0] == 'det':
                state.hold(item)
            elif item[0] == 'tick':
                state.tick(item[1])
            elif item[0] == 'handoff':
                _send(answers, state.take_handoff(*item[1:]))
            else:
                _send(answers, state.release(drain=True))
                if item[0] == 'layout':
                    _send(answers, state.set_layout(*item[1:]))
                else:
                    _send(answers, state.flush(item[1]))
        _send(answers, state.release())
        _send(answers, state.poll())


def _warm_up(settings: TrackerSettings) -> None:
    """Pay the first-call costs (imports, the associator, message type support) before the
    first detection arrives, so that its latency does not carry them."""
    try:
        state = TrackerState(settings, encode_tracks)
        state.set_layout(Layout(10.0, np.array([2.0, 4.0, 6.0])), (), ())
        for k in range(3):
            state.push_batch([('det', k, k, k, (1 + k) * NS_PER_S, 5.0, 2.0 + 2 * k, -1, 0.0, 0)])
        state.flush(0.0)
    except Exception:  # noqa: BLE001 - only a warm-up; real errors show on real input
        pass


def _send(answers, answer: Answer | None) -> None:
    if answer is not None:
        answer.sent_at = time.monotonic()
        answers.send(answer)
