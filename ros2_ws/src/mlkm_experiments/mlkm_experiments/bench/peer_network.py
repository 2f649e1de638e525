"""The peer on a road network: Stone Soup set up as on one road (``peer.stonesoup_associate``),
with the network's geometry given to it the way Stone Soup composes such knowledge: a
hypothesiser.

On one road a detection measures (the station's position along the road, the speed). A network
has no such common axis: after a diverge two stations may lie at the same distance from the
entry on different links, and a merge joins approaches of different lengths. So every track
measures along its own path: :class:`NetworkHypothesiser` wraps the ``DistanceHypothesiser``
and, for a track whose last detection was at station i, offers it only the detections at the
stations a vehicle can reach next from i (``network_assoc.network_hops``: the next stations,
or up to two further over stations passed unseen), each moved to the track's own coordinate:
the position of its last detection plus the hop's distance. A track's first detection is at
0 of its own axis. The moved copies compare equal to the detection they were made from
(:class:`Passage`: by its index), so that the global nearest-neighbour assignment and the
initiator see one detection, whichever track it was moved for.

The rest is the single road's setup: ``ConstantVelocity`` transition, ``LinearGaussian``
measurement of (position, speed), Kalman predictor and updater, Mahalanobis gate,
``GNNWith2DAssignment``, ``MultiMeasurementInitiator``, ``UpdateTimeDeleter``; the nominal
speed is the detections' median, and a track is kept without update for 1.5 x the longest hop
at the 5th-percentile speed plus the longest wait the network model allows before its fit
(``junctions.GENERIC_LOSS``: a red light of up to 90 s), so that no vehicle held at a junction
is dropped. It uses time and speed only, as on one road.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import replace

import numpy as np

from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc import MAX_SKIP, network_hops
from mlkm_core.types import Detections

from .peer import PeerConfig, run_tracker

#: the longest wait at a junction the network model allows before its fit [s]
LONGEST_WAIT = 90.0


def network_config(hops_distance: np.ndarray, det: Detections) -> PeerConfig:
    """The setup fitted to a network's detections (module docstring)."""
    base = PeerConfig()
    v = np.asarray(det.velocity, float)
    if v.size == 0:
        return base
    slow = max(float(np.percentile(v, 5)), 0.1)
    longest = float(np.max(hops_distance, initial=0.0))
    return replace(
        base,
        v_nominal=float(np.median(v)),
        delete_after=max(base.delete_after, 1.5 * longest / slow) + LONGEST_WAIT,
    )


def stonesoup_network_associate(
    net: RoadNetwork, det: Detections, cfg: PeerConfig | None = None
) -> np.ndarray:
    """Labels of ``det`` (its ``sensor_index`` indexes the network's stations) by Stone Soup
    (module docstring); -1 for detections in unconfirmed tracks."""
    from stonesoup.base import Property
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.hypothesiser.base import Hypothesiser
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.measures import Mahalanobis
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import ConstantVelocity
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.array import StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.updater.kalman import KalmanUpdater

    class Passage(Detection):
        """A detection, or its copy moved to a track's axis: equal by the detection's index."""

        def __eq__(self, other):
            return isinstance(other, Passage) and self.metadata['index'] == other.metadata['index']

        def __hash__(self):
            return hash(self.metadata['index'])

    class NetworkHypothesiser(Hypothesiser):
        """Offers a track the detections it can reach next, moved to its axis."""

        hypothesiser: Hypothesiser = Property(doc='the hypothesiser of the moved detections')
        reach: dict = Property(doc='(station, station) -> distance of the shortest hop [m]')

        def hypothesise(self, track, detections, timestamp, **kwargs):
            last = _last_measurement(track)
            if last is None:  # a track of no detection yet: its axis starts at the next one
                return self.hypothesiser.hypothesise(track, detections, timestamp, **kwargs)
            here, x = last.metadata['station'], float(last.state_vector[0, 0])
            moved = set()
            for m in detections:
                dist = self.reach.get((here, m.metadata['station']))
                if dist is not None:
                    moved.add(
                        Passage(
                            StateVector([[x + dist], [m.state_vector[1, 0]]]),
                            timestamp=m.timestamp,
                            measurement_model=m.measurement_model,
                            metadata=m.metadata,
                        )
                    )
            return self.hypothesiser.hypothesise(track, moved, timestamp, **kwargs)

    hops = network_hops(net, MAX_SKIP)
    reach: dict[tuple[int, int], float] = {}
    for s, t, x in zip(hops.src.tolist(), hops.dst.tolist(), hops.distance.tolist()):
        reach[(s, t)] = min(x, reach.get((s, t), np.inf))
    cfg = cfg or network_config(hops.distance, det)
    sx, sv = cfg.floor_position, cfg.floor_velocity  # the SUMO data carry no noise
    mm = LinearGaussian(ndim_state=2, mapping=(0, 1), noise_covar=np.diag([sx**2, sv**2]))
    predictor = KalmanPredictor(ConstantVelocity(cfg.q))
    updater = KalmanUpdater(mm)
    inner = DistanceHypothesiser(
        predictor, updater, measure=Mahalanobis(), missed_distance=cfg.gate
    )
    assoc = GNNWith2DAssignment(NetworkHypothesiser(inner, reach))
    base = dt.datetime(2000, 1, 1)
    scans = []
    for i in np.argsort(det.stamp, kind='stable').tolist():
        ts = base + dt.timedelta(seconds=float(det.stamp[i]))
        meta = {'index': i, 'station': int(det.sensor_index[i])}
        scans.append(
            (
                ts,
                {
                    Passage(
                        StateVector([[0.0], [det.velocity[i]]]),
                        timestamp=ts,
                        measurement_model=mm,
                        metadata=meta,
                    )
                },
            )  # fmt: skip
        )
    return run_tracker(scans, len(det), mm, updater, assoc, cfg, sx, sv)


def _last_measurement(track):
    """The measurement of the track's latest update, None before its first."""
    for state in reversed(track.states):
        m = getattr(getattr(state, 'hypothesis', None), 'measurement', None)
        if m is not None:
            return m
    return None
