"""Streaming association on an open road: detections for ever, vehicles in and out anywhere.

The batch associators solve a closed world (an episode with a known set of targets).
``StreamTracker`` runs any of them on an endless stream, where nobody knows how many
vehicles there are, vehicles enter at the first station or at on-ramps and leave after the
last station or at off-ramps, detections are missed and false alarms occur.

Mechanism
---------
1. **Immediate link.** Each ``push`` links the detection at once: the open tracks whose
   latest detection lies 1 to 1 + ``max_skip`` stations upstream are predicted to its
   station with the pairwise motion model (travel time and speed continuity, gated at
   6 sigma, the model's parameters calibrated on the stream); the cheapest gated track takes
   it if that beats starting a new track (cheaper right after an on-ramp and at the first
   station), else it starts a new TENTATIVE track. This is what a live consumer sees first.
2. **Revision in a window.** At every boundary B = k * ``solve_interval`` of stamp time, once
   the newest stamp is ``reorder_tolerance`` past B, the uncommitted detections stamped
   before B are re-solved together with *anchors*: the last ``anchor_depth`` committed
   detections of every open track. ``assignment`` and ``multiframe`` run natively on that
   window with the motion model calibrated on the stream's history (the last
   ``calibration_size`` committed detections plus the window, every ``calibration_every``
   solves): the sequential assignment, and for ``multiframe`` the Kalman and pairwise passes
   each refined by the multi-frame local search, keeping the more likely result; so a link
   is decided with evidence from the stations after it. Every other method (``mlkm``,
   ``mlkm_no_ec``, ``kmeans_*``, ``mlkm_robust``) runs its own ``associate`` on the window
   with the number of targets taken from the window (its largest per-station count). Before
   anything is committed every method runs its own ``associate``, so a lag longer than the
   input gives exactly the batch association.
3. **Stitching onto stable ids.** The window's clusters are mapped back through the anchors:
   walking a cluster in road order, a window detection joins the track of the last anchor met
   before it (the track's most recent committed detection), if it lies downstream of that
   track's detections so far; the rest of the cluster is a new group, which keeps the id of
   the tentative track most of its detections were in (or gets a new id). Committed
   detections never move.
4. **Commit.** After the solve at B every detection stamped before B - ``lag`` is committed
   for good: to its track if the track holds another detection stamped before B, else as a
   false alarm (-1). ``committed_until`` = B - ``lag``; a detection pushed with an older
   stamp is *late*: reported unassigned (and committed as -1) and counted. A detection waits
   between ``lag`` + ``reorder_tolerance`` and ``lag`` + ``reorder_tolerance`` +
   ``solve_interval`` of stamp time for its commit.
5. **End of a track.** A track whose detections before B are all committed becomes FINAL at
   B when its latest detection is at the last station, or when B is past the gate of its
   passage at the next station (if an off-ramp lies before it: it left there) or at the
   station 1 + ``max_skip`` further on (a missed detection does not end a track). A FINAL
   track leaves the working set with its detections, so memory stays bounded on an endless
   input. ``flush`` (the road fell quiet, or the input ended) solves and commits everything
   and makes every track FINAL.

Status: TENTATIVE while a track holds fewer than ``confirm_count`` detections, CONFIRMED from
then on (a revision that takes detections away can bring an uncommitted track back to
TENTATIVE), FINAL at its end. A track that lost all its detections to a revision is reported
once as FINAL with no keys; track ids are never reused.

Determinism. Every window solve, commit and end is a function of the detections stamped
before its boundary and of the earlier commits, never of the immediate links or of when a
push happened. So the committed association (which detections share a track, which are
false alarms) is the same whenever every push arrives less than ``reorder_tolerance`` after
a push with a stamp that much later: offline replay and the live node commit the same
association. Track ids are numbered in arrival order, so they are the same when the arrival
order is. A push older than the last solved boundary but not late (a delay beyond the
tolerance) is still associated and counted as ``reordered``. A ``flush`` in the middle of a
stream (the live node's quiet road) commits early what an uninterrupted stream would commit
at the next boundaries.
"""

from mlkm_core.streaming.config import (  # noqa: F401
    CONFIRMED,
    FINAL,
    TENTATIVE,
    StreamConfig,
    StreamUpdate,
    TrackUpdate,
)
from mlkm_core.streaming.tracker import StreamTracker  # noqa: F401
