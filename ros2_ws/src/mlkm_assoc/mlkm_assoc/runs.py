"""The EpisodeInfos of the source's current run and the recognition of a restart (ROS-free).

A restarted simulator numbers its episodes from 0 again. A new run is recognised by a layout
published later than the current run began (same content or not), an EpisodeInfo for a known
id with another window or number of targets, a STARTED for a known id published at another
time, or an EpisodeInfo for an already forgotten id published later than any of this run.
:class:`RunBook` keeps what the EpisodeInfos of this run said; the episode bookkeeping
(:mod:`mlkm_assoc.assembly`) closes the old run's episodes.
"""

from __future__ import annotations

Info = tuple[int, int, int]  # num_targets, start [ns], end [ns]


class RunBook:
    """EpisodeInfos of the current run: windows, STARTED stamps, ENDED counts."""

    def __init__(self) -> None:
        self.run_stamp = -1  # publication stamp of the message that began this run [ns]
        self.forget()

    def forget(self) -> None:
        """Forget every episode of the run (the run stamp stays)."""
        self.infos: dict[int, Info] = {}
        self.started: dict[int, int] = {}  # id -> publication stamp of its STARTED [ns]
        self.ended: dict[int, dict[int, int]] = {}  # id -> {sensor id: count}
        self.forgotten = -1  # episode ids up to this one were forgotten
        self.info_stamp = -1  # latest publication stamp of an EpisodeInfo of this run
        self.latest_start: int | None = None

    def is_new_run(self, episode_id: int, info: Info, started: bool, published_ns: int) -> bool:
        """Whether an EpisodeInfo (``started``: STARTED, else ENDED) begins a new run."""
        known = self.infos.get(episode_id)
        if known is not None:
            if known != info:
                return published_ns >= self.run_stamp
            first = self.started.get(episode_id)
            return (
                started
                and first is not None
                and published_ns != first
                and published_ns > self.run_stamp
            )
        return episode_id <= self.forgotten and published_ns > self.info_stamp

    def record(
        self,
        episode_id: int,
        info: Info,
        ended_counts: dict[int, int] | None,
        published_ns: int,
    ) -> None:
        """An EpisodeInfo of this run: STARTED (``ended_counts`` None) or ENDED."""
        self.info_stamp = max(self.info_stamp, published_ns)
        if episode_id not in self.infos:
            self.infos[episode_id] = info
            if self.latest_start is None or info[1] > self.latest_start:
                self.latest_start = info[1]
        if ended_counts is None:
            self.started.setdefault(episode_id, published_ns)
        else:
            self.ended[episode_id] = ended_counts

    def kept_for_new_run(self, run_stamp: int) -> dict[int, Info]:
        """The episodes whose STARTED was published at or after ``run_stamp`` (they already
        belong to the new run), when ``run_stamp`` is later than this run's."""
        return {
            k: v
            for k, v in self.infos.items()
            if self.started.get(k, -1) >= run_stamp and run_stamp > self.run_stamp
        }

    def restart(self, keep: dict[int, Info], run_stamp: int) -> None:
        """Begin the run of ``run_stamp``, keeping the EpisodeInfos of ``keep``."""
        started = {k: self.started[k] for k in keep if k in self.started}
        ended = {k: self.ended[k] for k in keep if k in self.ended}
        self.forget()
        self.infos, self.started, self.ended = keep, started, ended
        if keep:
            self.latest_start = max(start for _, start, _ in keep.values())
        self.run_stamp = max(self.run_stamp, run_stamp)

    def drop(self, episode_id: int) -> None:
        """Forget a finished episode (its later EpisodeInfos are stale)."""
        self.infos.pop(episode_id, None)
        self.started.pop(episode_id, None)
        self.ended.pop(episode_id, None)
        self.forgotten = max(self.forgotten, episode_id)
