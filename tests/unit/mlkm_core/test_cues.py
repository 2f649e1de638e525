"""The link model is made of parts: a cue added as one module and one registration is used
by every tracking method and by the stream tracker, and a link's cost is the motion term
plus the sum of the cues' terms."""

import warnings
from dataclasses import dataclass

import numpy as np
import pytest

from mlkm_core.associators import make_associator
from mlkm_core.associators.base import DegradedResultWarning
from mlkm_core.metrics import accuracy
from mlkm_core.model.catalogue import (
    available_cues,
    bind_cues,
    generic_cues,
    register_cue,
    unregister_cue,
)
from mlkm_core.model.cues import Cue, CueKind, CueTracks
from mlkm_core.model.link import LinkModel
from mlkm_core.model.motion import MotionParams, PairwiseModel
from mlkm_core.streaming import StreamConfig, StreamTracker
from mlkm_core.types import Detections, Layout

N_SENSORS = 12
SPACING = 200.0
#: cost [nats] of a link between detections of different colours
MISMATCH = 12.0


@dataclass(frozen=True)
class ColourParams:
    colours: dict  # (sensor, stamp) -> colour of the vehicle, as a sensor would report it


class ColourCue(Cue):
    """A toy cue: a sensor reports the vehicle's colour; a track keeps its colour."""

    name = 'colour'

    def __init__(self, d: Detections, params: ColourParams) -> None:
        keys = zip(d.sensor_index.tolist(), d.stamp.tolist(), strict=True)
        self.colour = np.array([params.colours.get(k, -1) for k in keys])

    def tracks(self, accumulate: bool) -> CueTracks:
        return ColourTracks(self, accumulate)


class ColourTracks(CueTracks):
    FIELDS = {'colour': (-1, np.int64)}

    def __init__(self, cue: ColourCue, accumulate: bool) -> None:
        super().__init__(accumulate)
        self.cue = cue

    def start(self, tracks, det):
        self.state['colour'][tracks] = self.cue.colour[det]

    def cost(self, tracks, det):
        a, b = self.state['colour'][tracks], self.cue.colour[det]
        return np.where((a >= 0) & (b >= 0) & (a != b), MISMATCH, 0.0)

    def update(self, tracks, det):
        self.state['colour'][tracks] = self.cue.colour[det]


def colour_kind(colours: dict) -> CueKind:
    params = ColourParams(colours)
    return CueKind(
        'colour',
        needs='reported colour',
        bind=lambda layout, d, p: ColourCue(d, p),
        fit=lambda layout, d, labels: params,
        generic=params,
    )


@pytest.fixture
def colour_cue():
    """Registers the toy cue for one test; yields a function that sets its colours."""
    kinds = {}

    def use(colours: dict) -> None:
        kinds['kind'] = colour_kind(colours)
        register_cue(kinds['kind'])

    yield use
    unregister_cue('colour')
    assert 'colour' not in available_cues()


def swapping_traffic():
    """Free-flow background traffic and two vehicles of different colours at the same speed
    0.1 s apart whose passage times are exchanged at one station: time and speed alone take
    the swap for noise, their colours tell it. Returns layout, detections and colours."""
    rng = np.random.default_rng(1)
    layout = Layout(SPACING * (N_SENSORS + 1), SPACING * np.arange(1, N_SENSORS + 1))
    sensor, stamp, speed, target = [], [], [], []
    for k in range(40):
        t, v = 8.0 * k + rng.uniform(0, 2), rng.uniform(25, 35)
        for s, x in enumerate(layout.positions):
            sensor.append(s)
            stamp.append(t + x / v + rng.normal(0, 0.05))
            speed.append(v + rng.normal(0, 0.2))
            target.append(k)
    for k, gap in enumerate((0.0, 0.1)):
        for s, x in enumerate(layout.positions):
            sensor.append(s)
            stamp.append(500.0 + (gap if s != 6 else 0.1 - gap) + x / 30.0)
            speed.append(30.0)
            target.append(40 + k)
    d = Detections(np.array(sensor), np.array(stamp), np.array(speed), np.array(target))
    colours = {
        (s, t): int(g % 2)
        for s, t, g in zip(sensor, d.stamp.tolist(), target, strict=True)
        if g >= 40
    }
    return layout, d, colours


def pair_correct(labels: np.ndarray, d: Detections) -> int:
    pair = d.target >= 40
    return accuracy(labels[pair], d.target[pair]).correct


def batch_labels(method: str, layout, d) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DegradedResultWarning)
        return make_associator(method).associate(layout, d, 42)


def stream_labels(method: str, layout, d) -> np.ndarray:
    tracker = StreamTracker(layout, StreamConfig(method=method, lag=30.0, solve_interval=5.0))
    labels = np.full(len(d), -2)
    updates = []
    for i in np.argsort(d.stamp, kind='stable'):
        updates.append(tracker.push(int(i), int(d.sensor_index[i]), d.stamp[i], d.velocity[i]))
    updates.append(tracker.flush())
    for u in updates:
        for key, track in u.committed.tolist():
            labels[key] = track
    assert np.all(labels >= -1)
    return labels


@pytest.mark.parametrize('method', ['assignment', 'multiframe', 'mlkm_robust'])
def test_a_registered_cue_is_used_by_every_tracking_method(method, colour_cue):
    layout, d, colours = swapping_traffic()
    # control: without the cue, the swap is taken as no swap
    assert pair_correct(batch_labels(method, layout, d), d) < 2 * N_SENSORS
    colour_cue(colours)
    assert pair_correct(batch_labels(method, layout, d), d) == 2 * N_SENSORS


@pytest.mark.slow
@pytest.mark.parametrize('method', ['assignment', 'multiframe'])
def test_a_registered_cue_is_used_by_the_stream_tracker(method, colour_cue):
    layout, d, colours = swapping_traffic()
    assert pair_correct(stream_labels(method, layout, d), d) < 2 * N_SENSORS
    colour_cue(colours)
    assert pair_correct(stream_labels(method, layout, d), d) == 2 * N_SENSORS


def test_a_link_costs_its_motion_term_plus_each_cue(colour_cue):
    layout, d, colours = swapping_traffic()
    colour_cue(colours)
    p = MotionParams(cues=bind_cues(layout, d, {'colour': ColourParams(colours)}))
    pair = np.flatnonzero(d.target >= 40)
    a = pair[(d.sensor_index[pair] == 0) & (d.target[pair] == 40)]  # colour 0 at station 0
    b = pair[d.sensor_index[pair] == 1]  # both colours at station 1
    u = 1.0 / d.velocity
    x = layout.positions
    model = LinkModel(p)
    model.grow(1)
    model.start(np.array([0]), x[0], d.stamp[a], u[a], a)
    rows = np.zeros(b.size, np.int64)
    nll, d2 = model.cost(model.predict(rows, x[1]), d.stamp[b], u[b], b)
    motion = PairwiseModel(p)
    motion.grow(1)
    motion.start(np.array([0]), x[0], d.stamp[a], u[a])
    m_nll, m_d2 = motion.cost(motion.predict(rows, x[1]), d.stamp[b], u[b])
    expected = m_nll + np.where(d.target[b] == 41, MISMATCH, 0.0)
    np.testing.assert_allclose(nll, expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(d2, m_d2)


def test_a_cue_name_is_registered_once(colour_cue):
    colour_cue({})
    with pytest.raises(ValueError, match='registered twice'):
        register_cue(colour_kind({}))
    assert available_cues()[:3] == ['lane_order', 'length', 'lane']


def test_a_cue_left_off_says_why():
    layout, d, _ = swapping_traffic()
    lengths = 4.0 + (d.target % 3) * 2.0  # 4, 6 and 8 m vehicles
    with_length = Detections(d.sensor_index, d.stamp, d.velocity, d.target, None, lengths)
    cues = generic_cues(layout, with_length)
    assert [c.name for c in cues.cues] == ['length']
    assert cues.off == {
        'lane': 'the detections hold no known lanes, two or more',
        'lane_order': 'not fitted: no queue in a lane (travel times that cannot tell '
        'neighbours apart) found',
    }
    assert generic_cues(layout, d) is None  # neither lane nor length: no cue at all
    # every vehicle 4.5 m long on one lane: neither tells a vehicle from another
    same = Detections(
        d.sensor_index, d.stamp, d.velocity, d.target, np.zeros(len(d), int), np.full(len(d), 4.5)
    )
    assert generic_cues(layout, same) is None
