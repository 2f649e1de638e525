"""When an episode's work goes to the solver (ROS-free): its complete segments strictly in
segment order, then its final association, or, forced by a timeout or a new run, whatever it
has. Counts the segments, the finals, the episodes never seen and the missing detections
(the policies are in :mod:`mlkm_assoc.assembly`'s docstring).
"""

from __future__ import annotations

from collections.abc import Callable

from mlkm_assoc.episodes import Episode, Job


class Completion:
    """Submits the jobs of episodes through ``submit`` and keeps the counts."""

    def __init__(self, submit: Callable[[Job], None]) -> None:
        self._submit = submit
        self.segments_done = 0
        self.episodes_final = 0
        self.episodes_unseen = 0  # episodes this node saw no detection of (no final)
        self.missing = 0  # detections ENDED announced that never arrived

    def advance(self, ep: Episode, now: float, forced: bool = False) -> bool:
        """Submit ``ep``'s complete segments in order (every one when ``forced``), then its
        final when every sensor is done after ENDED (or when ``forced``). True once the
        final went out: the episode is finished."""
        while ep.next_segment < len(ep.segments):
            seg = ep.segments[ep.next_segment]
            if not forced and not all(ep.sensor_done(s) for s in seg):
                return False
            self._submit(ep.job('segment', (ep.part(seg),), now, forced))
            ep.next_segment += 1
            self.segments_done += 1
        if not forced:
            if ep.ended is None or not all(ep.sensor_done(s) for s in range(len(ep.seg_of))):
                return False
        if ep.dirty:
            parts = tuple(ep.part(seg) for seg in ep.segments)
            self._submit(ep.job('rerun', parts, now, forced))
        else:
            self._submit(ep.job('final', (), now, forced))
        self.missing += ep.missing()
        self.episodes_final += 1
        return True

    def force(self, ep: Episode, now: float) -> bool:
        """Finalise ``ep`` with what it has; without a single detection: no final at all.
        Always True: the episode is finished."""
        if ep.accepted == 0:
            self.episodes_unseen += 1
            self.missing += ep.missing()
            return True
        return self.advance(ep, now, forced=True)
