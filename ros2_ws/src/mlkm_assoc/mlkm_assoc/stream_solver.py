"""Stream mode's solver process: the tracker's window solves, beside the tracker process.

The tracker process (:mod:`mlkm_assoc.stream_worker`) must answer every detection within
milliseconds, but a window solve of the core's ``StreamTracker`` takes up to seconds. So the
tracker gets a ``SolverClient`` as its executor: ``submit`` sends the window's problem (plain
arrays, see :mod:`mlkm_core.streaming.solve`) to this process and returns at once; the
tracker applies the solution at its boundary once ``done``. Solves run one at a time, in
the order submitted. Both processes are children of the node (a daemonic process has no
children of its own), connected by two pipes.

The solver runs as a batch job (SCHED_BATCH): it keeps its fair share of the CPU but does not
preempt the node or the tracker process when they wake up, since a detection's latency
depends on them getting the CPU when it arrives, while a solve only has to be done before
its commits are due. When the machine cannot do both, the commits fall behind
(``stream.commit_lag`` in /diagnostics). A niceness on top of SCHED_BATCH gave no better
latency and starved the solves while a fast source took a core (measurements:
docs/benchmarks.md#stream-node-internals, ``mlkm bench --only stream``).
"""

from __future__ import annotations

import math
import os
import time
from collections import deque
from typing import Any

from mlkm_ros.lifecycle import helper_process, start_helper

#: Shortest time between two looks at the result pipe from ``done`` [s]: the tracker asks at
#: every push, and a look is a system call.
LOOK_PERIOD = 0.002


class SolverProcess:
    """The solver process, started by the node; ``ends`` go to the tracker process."""

    def __init__(self, ctx) -> None:
        request_reader, request_writer = ctx.Pipe(duplex=False)
        result_reader, result_writer = ctx.Pipe(duplex=False)
        self._requests = request_writer
        self._proc = start_helper(
            ctx, _serve, (request_reader, result_writer, os.getpid()), 'mlkm_stream_solver'
        )
        request_reader.close()
        result_writer.close()
        #: (send end of the requests, receive end of the results) for the SolverClient
        self.ends = (request_writer, result_reader)

    def close(self, timeout: float = 5.0) -> None:
        if self._proc.is_alive():
            try:
                self._requests.send(None)
            except (BrokenPipeError, OSError):
                pass
            self._proc.join(timeout)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(2.0)


class SolveFailed(RuntimeError):
    """The solver process raised, or is gone (the tracker then solves the window itself)."""


class SolverClient:
    """The tracker's executor (``submit(fn, *args)`` returning a future with ``done`` and
    ``result``), solving in the solver process."""

    def __init__(self, ends) -> None:
        self._requests, self._results = ends
        self._waiting: deque[_Future] = deque()
        self._looked = -math.inf  # monotonic time of the last non-blocking look

    def submit(self, fn, *args) -> _Future:
        future = _Future(self)
        try:
            self._requests.send((fn, args))
        except (BrokenPipeError, OSError) as exc:
            raise SolveFailed(f'solver process gone: {exc}') from exc
        self._waiting.append(future)
        return future

    def _collect(self, block: bool) -> None:
        """Take the answers that arrived (``block``: wait for the next one)."""
        if not block:
            now = time.monotonic()
            if now - self._looked < LOOK_PERIOD:
                return
            self._looked = now
        while self._waiting and (block or self._results.poll()):
            future = self._waiting.popleft()
            try:
                future._outcome = self._results.recv()
            except (EOFError, OSError) as exc:
                future._outcome = ('error', f'solver process gone: {exc}')
            block = False


class _Future:
    def __init__(self, client: SolverClient) -> None:
        self._client = client
        self._outcome: tuple[str, Any] | None = None

    def done(self) -> bool:
        if self._outcome is None:
            self._client._collect(False)
        return self._outcome is not None

    def result(self) -> Any:
        while self._outcome is None:
            self._client._collect(True)
        kind, value = self._outcome
        if kind != 'ok':
            raise SolveFailed(value)
        return value


def _serve(requests, results, parent: int) -> None:
    """Process main loop: (function, arguments) in, ('ok', value) or ('error', text) out."""
    helper_process(parent)  # Ctrl-C is for the node, which stops us; we die with it
    try:
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    except (OSError, AttributeError):
        pass  # not available here: solves compete with the pushes on equal terms
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:
        pass
    import mlkm_core.streaming.solve  # noqa: F401  (pay the imports before the first solve)

    while True:
        try:
            if not requests.poll(1.0):
                if os.getppid() != parent:
                    return
                continue
            request = requests.recv()
        except (EOFError, OSError):
            return
        if request is None:
            return
        fn, args = request
        try:
            outcome = ('ok', fn(*args))
        except Exception as exc:  # noqa: BLE001 - reported to the tracker, which solves itself
            outcome = ('error', f'{type(exc).__name__}: {exc}')
        try:
            results.send(outcome)
        except (BrokenPipeError, OSError):
            return
