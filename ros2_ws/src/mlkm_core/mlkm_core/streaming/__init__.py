"""Streaming association on an open road: detections for ever, vehicles in and out anywhere.

The batch associators solve a closed world (an episode with a known set of targets).
``StreamTracker`` runs any of them on an endless stream, where nobody knows how many
vehicles there are, vehicles enter at the first station or at on-ramps and leave after the
last station or at off-ramps, detections are missed and false alarms occur.

Mechanism
---------
1. **Immediate link.** Each ``push`` links the detection at once: the open tracks whose
   latest detection lies 1 to 1 + ``max_skip`` stations upstream (or as far downstream, for
   a track without a detection at its station: stamps out of road order under noise) are
   predicted to its station with the pairwise motion model (travel time and speed
   continuity, gated at 6 sigma, the model's parameters calibrated on the stream); the
   cheapest gated track takes it if that beats starting a new track (cheaper right after an
   on-ramp and at the first station), else it starts a new TENTATIVE track. This is what a
   live consumer sees first; the *revision rate* is the share of committed detections whose
   link first published (the detection it followed in its track, or none) changed.
2. **Revision in a window.** At every boundary B = k * ``solve_interval`` of stamp time, once
   the newest stamp is ``reorder_tolerance`` past B, the uncommitted detections stamped
   before B are re-solved together with *anchors*: the last ``anchor_depth`` committed
   detections of every open track. The configured method's own batch ``associate`` solves
   that window (with lane and length where the sensors report them), so every registered
   method works in stream mode: ``assignment`` and ``multiframe`` as fixed-lag trackers
   (``multiframe`` with its Kalman pass and multi-frame local search inside the window, so a
   link is decided with evidence from the stations after it), the paper's ``mlkm``,
   ``mlkm_no_ec``, ``kmeans_*`` and ``mlkm_robust`` over the sliding window with the number of
   clusters estimated from the window (its largest per-station count). The anchors carry the
   open tracks' recent history into the window. ``assignment``, ``multiframe`` and
   ``mlkm_robust`` calibrate their motion model on their input: they do so on the first
   window and then every ``calibration_every`` windows, given also the detections of the
   most recently ended tracks (``context_size``) so that sparse traffic still gives them
   enough tracks (their clusters are not used); the windows in between get that model
   carried over (``solve.CarriedModel``; not a model that learnt a queue's order within
   lanes, which is bound to its own detections, and not one estimated on fewer rows than a
   full context, as on a road that is filling up: then the next window calibrates again).
   What a method decides about the traffic rather than about a window (``multiframe``:
   whether vehicles keep a cruise speed, which picks the motion model of its search) is
   decided on the evidence of every window so far (``Associator.settled``; the tracker adds
   each window's for the share of its rows it commits, the older fading past
   ``solve.EVIDENCE_WEIGHT``), so the windows do not flip between models. Where vehicles
   enter and leave mid-road (a road observed over part of its length, undeclared side
   streets), a window cannot tell a vehicle that did from one its edges cut: each window
   prices the tracks it begins and ends by the entry and exit rates of the tracks the
   stream has ended, which are whole (``entries``). With a lag longer than the input
   nothing is committed before ``flush``, whose window is the whole input, holds every
   vehicle's passages and calibrates on them as batch does: the stream gives exactly the
   batch association.
3. **Stitching onto stable ids.** The window's clusters are mapped back through the anchors:
   a cluster holding the last committed detection of an open track continues that track (of
   several such tracks, each takes the cluster's window detections from its own last
   station on), except at a station where the track already has a committed detection;
   the rest of a cluster is a new group, which keeps the id of the tentative track most of
   its detections were in (or gets a new id). Committed detections never move.
4. **Commit.** After the solve at B every detection stamped before B - ``lag`` is committed
   for good: to its track if the track holds another detection stamped before B, else as a
   false alarm (-1). ``committed_until`` = B - ``lag``; a detection pushed with an older
   stamp is *late*: reported unassigned (and committed as -1) and counted. A detection waits
   between ``lag`` + ``reorder_tolerance`` and ``lag`` + ``reorder_tolerance`` +
   ``solve_interval`` of stamp time for its commit.
5. **End of a track.** A track whose detections before B are all committed becomes FINAL at
   B when its latest detection is at the last station, or when B is past the gate of its
   passage at the next station (if an off-ramp lies before it: it left there) or at the
   station 1 + ``max_skip`` further on (a missed detection does not end a track). The
   pairwise model used for this and for the immediate link is the method's calibrated model
   (for the K-means methods: calibrated every ``calibration_every`` solves on the last
   ``calibration_size`` committed detections and the window). A track's latest detection
   stops being a candidate of the immediate link once that gate has passed, before its
   track is finalised. A FINAL track leaves the working set with its detections, so memory
   stays bounded on an endless input. ``flush`` (the road fell quiet, or the input ended) solves
   and commits everything and makes every track FINAL.

Solving beside the stream. A window solve takes up to seconds. Given an ``executor`` (an
object with ``submit(fn, *args)`` returning a future: a ``concurrent.futures`` executor, or
the live node's solver process), ``push`` never solves: at a due boundary it snapshots the
window's problem (``mlkm_core.streaming.solve.WindowProblem``: the window, anchors and
context as plain arrays; ``solve`` is a pure function of it) and submits it, and returns with
the immediate link. ``push`` and ``poll`` (call it every few milliseconds while ``solving``)
apply a finished solve at its boundary (steps 3 to 5) and submit the next due one: solves
run one at a time, in boundary order, each from the commits of the one before; the
detections pushed meanwhile whose tracks the solve changed are linked again at once.
``flush`` waits for them. Commits come later in wall time, never different: without an
executor each solve runs inside the ``push`` whose stamp made its boundary due.

Overload. When the solves cannot keep up, the detections waiting for their commit pile up and
each window grows. Beyond ``max_uncommitted`` of them the tracker drops the solve in flight
and commits every due boundary at once on the tracks the detections are in (their immediate
links, revised by the solves applied before), ends the tracks that are over and submits no
solve while the dropped one may still run: the backlog and the commit lag stay bounded, and
the committed labels are the immediate association's instead of the window's (``overloaded``
until a solve is applied again; counters ``skipped_solves`` and ``forced_commits``).

Status: TENTATIVE while a track holds fewer than ``confirm_count`` detections, CONFIRMED from
then on (a revision that takes detections away can bring an uncommitted track back to
TENTATIVE), FINAL at its end. A track that lost all its detections to a revision is reported
once as FINAL with no keys; track ids are never reused.

Determinism. Every window solve, commit and end is a function of the detections stamped
before its boundary and of the earlier commits, never of the immediate links or of when a
push happened. So the committed association (which detections share a track, which are
false alarms) is the same as long as no detection is pushed after one stamped
``reorder_tolerance`` or more later than it: offline replay and the live node commit the same
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
