"""Runs the core's associator on the segments the assembler hands over (ROS-free).

One incremental core session per episode (``Associator.session``): each completed segment is
fed with ``add_segment`` and the labels of everything fed so far come back. Track numbers
are kept stable from one update to the next (the new labels are matched to the previous
track ids by the largest overlap, Hungarian), so a downstream tracker sees the same id for
the same target in the partial and the final output. When the associator moves every
detection of a published track to other tracks (two segment clusters linked into one, for
example), that id is retired: each later update of the episode names it in
``Result.retired``, and it is never given to another track.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from mlkm_assoc.episodes import Job, Part
from mlkm_core.associators.base import Session
from mlkm_core.network_assoc.stations import associator_for
from mlkm_core.types import UNASSIGNED, Detections, Layout

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class Result:
    """One association update: every detection of the episode fed so far, and its track."""

    episode_id: int
    method: str
    final: bool
    segments_done: int
    segments_total: int
    layout: Layout
    sensor_index: np.ndarray
    stamps_ns: np.ndarray
    velocities: np.ndarray
    labels: np.ndarray  # stable track id, or UNASSIGNED
    solve_time: float  # [s]
    completed_at: float  # monotonic time the segment was complete
    forced: bool
    error: str | None = None
    started_at: float = 0.0  # monotonic time the solver took the job
    missing: int = 0  # detections ENDED announced that the node never received [-]
    lanes: np.ndarray | None = None  # lane of each detection, -1 unknown
    lengths: np.ndarray | None = None  # measured vehicle length [m], NaN unknown
    # ids of tracks an earlier update of this episode published that hold no detection now
    retired: tuple[int, ...] = ()


class _EpisodeSolve:
    def __init__(self) -> None:
        self.session: Session | None = None
        self.fed: list[Part] = []
        self.ids = np.zeros(0, dtype=np.int64)  # stable ids, aligned with the fed order
        self.segments_done = 0
        self.published: set[int] = set()  # every id an update of this episode carried

    def next_id(self) -> int:
        """The smallest id no update of this episode has used (a retired id stays retired)."""
        return max(self.published) + 1 if self.published else 0

    def publish(self) -> tuple[int, ...]:
        """Record the current ids as published; the ids published before and gone now."""
        current = set(np.unique(self.ids[self.ids >= 0]).tolist())
        self.published |= current
        return tuple(sorted(self.published - current))


def _concat(parts: list[Part]) -> tuple[np.ndarray, ...]:
    """(sensor_index, stamps_ns, velocities, lanes, lengths) of ``parts`` in order."""
    if not parts:
        return (
            np.zeros(0, np.int64),
            np.zeros(0, np.int64),
            np.zeros(0),
            np.zeros(0, np.int64),
            np.zeros(0),
        )
    return (
        np.concatenate([p.sensor_index for p in parts]),
        np.concatenate([p.stamps_ns for p in parts]),
        np.concatenate([p.velocities for p in parts]),
        np.concatenate([p.lanes for p in parts]),
        np.concatenate([p.lengths for p in parts]),
    )


def _keys(si: np.ndarray, ns: np.ndarray, lanes: np.ndarray, vel: np.ndarray) -> list[tuple]:
    """One key per detection: (sensor index, stamp, lane, velocity) tells apart everything
    the assembler accepted (a lane-unknown duplicate is refused on sensor, stamp, velocity)."""
    return list(zip(si.tolist(), ns.tolist(), lanes.tolist(), vel.tolist()))


def to_detections(part: Part) -> Detections:
    """The core's view of a segment: stamps in seconds (float64) from integer ns, with the
    lane and measured length of every detection."""
    return Detections(
        part.sensor_index,
        part.stamps_ns / NS_PER_S,
        part.velocities,
        lane=part.lanes,
        length=part.lengths,
    )


def stable_ids(previous: np.ndarray, labels: np.ndarray, first_free: int = 0) -> np.ndarray:
    """Rename ``labels`` so that they agree with ``previous`` ids where possible.

    ``previous`` holds the earlier ids of the first ``len(previous)`` detections
    (UNASSIGNED where none). New labels are matched one-to-one to previous ids maximising
    shared detections; unmatched labels get fresh ids, none below ``first_free`` (ids in use
    earlier are not handed out again). UNASSIGNED stays UNASSIGNED.
    """
    labels = np.asarray(labels, dtype=np.int64)
    out = np.full(labels.shape, UNASSIGNED, dtype=np.int64)
    new_vals = np.unique(labels[labels >= 0])
    if new_vals.size == 0:
        return out
    mapping: dict[int, int] = {}
    n_prev = previous.size
    prev_vals = np.unique(previous[previous >= 0])
    if n_prev and prev_vals.size:
        head_new, head_prev = labels[:n_prev], previous
        both = (head_new >= 0) & (head_prev >= 0)
        if both.any():
            rows = np.searchsorted(new_vals, head_new[both])
            cols = np.searchsorted(prev_vals, head_prev[both])
            table = np.zeros((new_vals.size, prev_vals.size), dtype=np.int64)
            np.add.at(table, (rows, cols), 1)
            r, c = linear_sum_assignment(table, maximize=True)
            for i, j in zip(r, c):
                if table[i, j] > 0:
                    mapping[int(new_vals[i])] = int(prev_vals[j])
    next_id = max(int(prev_vals.max()) + 1 if prev_vals.size else 0, first_free)
    used = set(mapping.values())
    for v in new_vals.tolist():
        if v not in mapping:
            while next_id in used:
                next_id += 1
            mapping[v] = next_id
            used.add(next_id)
    lookup = np.array([mapping[v] for v in new_vals.tolist()], dtype=np.int64)
    valid = labels >= 0
    out[valid] = lookup[np.searchsorted(new_vals, labels[valid])]
    return out


class Solver:
    """Turns jobs into results; keeps one core session per open episode."""

    def __init__(self) -> None:
        self._episodes: dict[int, _EpisodeSolve] = {}

    def run(self, job: Job) -> Result:
        started_at = time.monotonic()
        t0 = time.perf_counter()
        error = None
        if job.kind == 'segment':
            state = self._episodes.setdefault(job.episode_id, _EpisodeSolve())
            labels, error = self._add(state, job, job.parts[0])
            state.ids = stable_ids(state.ids, labels, state.next_id())
        elif job.kind == 'final':
            state = self._episodes.pop(job.episode_id, None) or _EpisodeSolve()
        else:  # 'rerun': associate everything again, from scratch
            old = self._episodes.pop(job.episode_id, None) or _EpisodeSolve()
            si, ns, vel, ln, _ = _concat(old.fed)
            previous = dict(zip(_keys(si, ns, ln, vel), old.ids.tolist()))
            state = _EpisodeSolve()
            state.published = old.published
            labels = None
            for part in job.parts:
                labels, error = self._add(state, job, part)
                if error:
                    break
            if error or labels is None:
                state.fed = list(job.parts)
                labels = np.full(sum(p.stamps_ns.size for p in job.parts), UNASSIGNED, np.int64)
            si, ns, vel, ln, _ = _concat(state.fed)
            aligned = np.array(
                [previous.get(k, UNASSIGNED) for k in _keys(si, ns, ln, vel)], dtype=np.int64
            )
            state.ids = stable_ids(aligned, labels, old.next_id())
            state.segments_done = len(job.parts)
        solve_time = time.perf_counter() - t0
        retired = state.publish()
        si, ns, vel, lanes, lengths = _concat(state.fed)
        return Result(
            episode_id=job.episode_id,
            method=job.method,
            final=job.kind != 'segment',
            segments_done=state.segments_done,
            segments_total=job.segments_total,
            layout=job.layout,
            sensor_index=si,
            stamps_ns=ns,
            velocities=vel,
            labels=state.ids,
            solve_time=solve_time,
            completed_at=job.completed_at,
            forced=job.forced,
            error=error,
            started_at=started_at,
            missing=job.missing,
            lanes=lanes,
            lengths=lengths,
            retired=retired,
        )

    @staticmethod
    def _add(state: _EpisodeSolve, job: Job, part: Part) -> tuple[np.ndarray, str | None]:
        """Feed one segment to the episode's session; on failure every label is UNASSIGNED."""
        state.fed.append(part)
        state.segments_done += 1
        n_total = sum(p.stamps_ns.size for p in state.fed)
        try:
            if state.session is None:
                # a road network's stations get the network method (its docstring)
                associator = associator_for(job.layout, job.method, job.associator_config)
                state.session = associator.session(job.layout, job.n_targets)
            labels = np.asarray(state.session.add_segment(to_detections(part)), np.int64)
            if labels.shape != (n_total,):
                raise ValueError(f'{labels.size} labels for {n_total} detections')
            return labels, None
        except Exception as exc:  # noqa: BLE001 - reported; the node keeps running
            return (
                np.full(n_total, UNASSIGNED, dtype=np.int64),
                f'{job.method} failed on episode {job.episode_id}, segment '
                f'{state.segments_done - 1}: {type(exc).__name__}: {exc}',
            )


Encoder = Callable[[Result], Any]


class SolverProcess:
    """The solver in a process of its own, so that solving never holds the GIL of the node's
    executor thread (fast ingest) and runs on the other core. Jobs go in with ``submit``;
    ``encode(result)`` of each comes out of ``get`` in the same order (None once closed).
    ``encode`` runs in the solver process: it must be a module-level function (picklable)."""

    def __init__(self, encode: Encoder) -> None:
        ctx = multiprocessing.get_context('spawn')
        self._jobs = ctx.Queue()
        # Results come back through a pipe written synchronously by the solver's main thread
        # (a Queue's feeder thread would wait for the GIL behind the next solve).
        self._results, sender = ctx.Pipe(duplex=False)
        # mlkm_ros.lifecycle imports no ROS; imported here so that this module loads none of
        # the mlkm_ros package
        from mlkm_ros.lifecycle import start_helper

        self._proc = start_helper(
            ctx, _serve, (self._jobs, sender, os.getpid(), encode), 'mlkm_solver'
        )
        sender.close()  # the child holds the only writer: its exit ends get() with None

    def submit(self, job: Job | None) -> None:
        self._jobs.put(job)

    def get(self) -> Any:
        try:
            return self._results.recv()
        except (EOFError, OSError):
            return None

    def close(self, timeout: float = 5.0) -> None:
        if self._proc.is_alive():
            self._jobs.put(None)
            self._proc.join(timeout)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(2.0)
        # The process is gone: jobs still queued are never taken, and the queue's feeder
        # thread, writing them into a full pipe, would hold up the exit of the node for ever.
        self._jobs.cancel_join_thread()
        self._jobs.close()


def _serve(jobs, results, parent: int, encode: Encoder) -> None:
    """Solver process main loop; exits on None or when the node's process is gone."""
    import queue as _queue

    from mlkm_ros.lifecycle import helper_process

    helper_process(parent)  # Ctrl-C is for the node, which stops us; we die with it
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)  # one core for the solver: the other one is the node's
    except ImportError:
        pass
    _warm_up(encode)
    solver = Solver()
    while True:
        try:
            job = jobs.get(timeout=1.0)
        except _queue.Empty:
            if os.getppid() != parent:
                return
            continue
        if job is None:
            results.send(None)
            results.close()
            return
        results.send(encode(solver.run(job)))


def _warm_up(encode: Encoder) -> None:
    """Pay the first-call costs (imports, sklearn and message type support) before the first
    real segment arrives, so that its latency is not inflated by them."""
    from mlkm_core.associators.base import AssociatorConfig
    from mlkm_core.types import Layout

    layout = Layout(10.0, np.array([2.0, 4.0, 6.0]))
    rng = np.random.default_rng(0)
    n = 3
    stamps = np.concatenate([np.arange(n) * 10.0 + p / 5.0 for p in (2.0, 4.0, 6.0)])
    part = Part(
        np.repeat(np.arange(3), n), (stamps * 1e9).astype(np.int64), 5.0 + rng.random(3 * n)
    )
    job = Job(
        kind='segment',
        episode_id=0,
        layout=layout,
        n_targets=n,
        method='mlkm',
        associator_config=AssociatorConfig(segment_size=3),
        segments_total=1,
        parts=(part,),
        completed_at=0.0,
    )
    try:
        encode(Solver().run(job))
    except Exception:  # noqa: BLE001 - only a warm-up; real errors show on real jobs
        pass
