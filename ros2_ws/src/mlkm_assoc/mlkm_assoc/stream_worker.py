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
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections import deque

import numpy as np

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

#: Queued items (detections and ticks) taken as one batch at most [-].
MAX_BATCH = 512
#: Wait for queued items while a window solve is in flight [s]: how often it is polled.
POLL_PERIOD = 0.005
#: Sent by the tracker process once it has warmed up, before any Answer.
READY = 'ready'


class TrackerProcess:
    """The tracker process: items go in with ``put``; ``get`` returns each Answer (None once
    the process ended)."""

    def __init__(self, settings: TrackerSettings) -> None:
        self._ready = threading.Event()
        ctx = multiprocessing.get_context('spawn')
        self._solver = SolverProcess(ctx)
        items, item_sender = ctx.Pipe(duplex=False)
        self._answers, sender = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(
            target=_serve,
            args=(items, sender, os.getpid(), settings, self._solver.ends),
            name='mlkm_stream_tracker',
            daemon=True,
        )
        self._proc.start()
        sender.close()
        items.close()
        self._items = _BatchSender(item_sender)

    def put(self, item: Item | None) -> None:
        self._items.put(item)

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

    def wait_ready(self, timeout: float) -> bool:
        """Wait until the process has warmed up (needs a reader calling ``get``); False if it
        did not within ``timeout`` seconds."""
        return self._ready.wait(timeout)

    def close(self, timeout: float = 5.0) -> None:
        if self._proc.is_alive():
            self._items.put(None)
            self._proc.join(timeout)
        self._items.close()
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(2.0)
        self._solver.close()


class _BatchSender:
    """Items to the tracker process from a thread of its own, as lists: whatever queued up
    while the last list was written goes in the next one (one pickle and one write per list,
    not per detection; one item per list while the rate is low)."""

    def __init__(self, conn) -> None:
        self._conn = conn
        self._items: deque[Item | None] = deque()
        self._wake = threading.Event()
        self._thread = threading.Thread(target=self._run, name='stream_sender', daemon=True)
        self._thread.start()

    def put(self, item: Item | None) -> None:
        self._items.append(item)
        self._wake.set()

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


def _serve(items, answers, parent: int, settings: TrackerSettings, solver_ends=None) -> None:
    """Process main loop: lists of items in, detections through the reorder buffer into the
    tracker, one Answer per batch of at most MAX_BATCH items out."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the node stops us; Ctrl-C is for it
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:
        pass
    _warm_up(settings)
    executor = SolverClient(solver_ends) if solver_ends is not None else None
    state = TrackerState(settings, encode_tracks, executor)
    answers.send(READY)
    pending: deque[Item | None] = deque()
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
