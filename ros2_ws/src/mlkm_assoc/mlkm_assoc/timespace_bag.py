"""The time-space diagram's input from a bag the product recorded (``mlkm plot --input BAG``).

Reads ``/mlkm/tracks``, ``/road/sensor_layout`` and ``/road/ground_truth`` with the
product's bag reader (:mod:`rosbag_mcap.reader`: a bag directory or a lone .mcap, a damaged
file as far as it is readable) and decodes them with ``mcap-ros2-support`` against the
definitions recorded in the bag, so that a bag recorded with an older version of the
messages (fewer fields) decodes too.

Each track is taken in its final version: a TrackArray carries a partial or changed set of
tracks (after each road segment in episodes mode, the changed tracks in stream mode), so a
detection belongs to the track, or the unassigned list, that carried it last. Detections are
identified as the scorer joins them, by (sensor id, lane, stamp); tracks by (episode, track
id), so that the episodes of one bag never share a track. Ground truth marks the wrong links
(:mod:`mlkm_core.timespace`); true targets are told apart per episode as well.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from mlkm_assoc.timespace_plot import PlotInput, on_route
from mlkm_core.timespace import NO_TRUTH
from mlkm_core.types import FALSE_ALARM, UNASSIGNED
from mlkm_ros import qos

TRACKS = '/' + qos.TRACKS_TOPIC
LAYOUT = '/' + qos.LAYOUT_TOPIC
TRUTH = '/' + qos.GROUND_TRUTH_TOPIC
#: GroundTruth.FALSE_ALARM: the target_id of clutter.
TRUTH_FALSE_ALARM = 2**32 - 1
NS_PER_S = 1_000_000_000


class _Decoders:
    """Message decoders of a bag's topics, built from the definitions recorded in it."""

    def __init__(self, reader) -> None:
        self.reader = reader
        self.by_topic: dict = {}

    def __call__(self, message):
        decode = self.by_topic.get(message.topic)
        if decode is None:
            from mcap_ros2._dynamic import generate_dynamic

            definition = self.reader.definition(message.topic)
            if not definition:
                raise ValueError(f'{message.topic}: the bag holds no message definition')
            decode = generate_dynamic(message.type, definition)[message.type]
            self.by_topic[message.topic] = decode
        return decode(message.data)


def _ns(t) -> int:
    return int(t.sec) * NS_PER_S + int(t.nanosec)


def read_bag(
    bag: str | Path, tracks: Iterable | None = None, route: str | None = None
) -> PlotInput:
    """The detections of a bag with their final tracks and, when recorded, their truth.

    ``tracks``: TrackArray messages (rclpy's or decoded ones) to draw instead of the bag's
    own, e.g. those of a replay of the bag into fresh nodes. On a road network the detections
    of one route (``route``, link names comma-separated; None: the route with the most
    stations; ``timespace_plot.on_route``).

    Raises ValueError when the bag cannot be opened or holds no tracks."""
    from mcap.exceptions import McapError

    from rosbag_mcap.metadata import BagError
    from rosbag_mcap.reader import BagReader

    bag = Path(bag)
    if not bag.exists():
        raise ValueError(f'{bag}: no such bag')
    try:
        reader = BagReader(bag)
    except BagError as exc:
        raise ValueError(str(exc)) from None
    decode = _Decoders(reader)
    station_of: dict[int, float] = {}  # sensor id -> position [m], from the layout
    seen_at: dict[int, float] = {}  # sensor id -> position [m], from the tracks
    track_of: dict[tuple, tuple | None] = {}  # detection -> (episode, track id), None
    truth_of: dict[tuple, tuple | None] = {}  # detection -> (episode, target), None = clutter
    arrays = 0
    network = None
    topics = [LAYOUT, TRUTH] + ([TRACKS] if tracks is None else [])
    try:
        for message in reader.messages(topics=topics):
            msg = decode(message)
            if message.topic == LAYOUT:
                if len(getattr(msg, 'link_ids', ())):
                    # positions along different links share no axis: one route of it
                    network = _network(msg)
                station_of = dict(zip(map(int, msg.sensor_ids), map(float, msg.positions)))
            elif message.topic == TRUTH:
                stamp = _ns(msg.header.stamp)
                key = (int(msg.sensor_id), int(getattr(msg, 'lane', -1)), stamp)
                clutter = msg.false_alarm or msg.target_id == TRUTH_FALSE_ALARM
                truth_of[key] = None if clutter else (int(msg.episode_id), int(msg.target_id))
            else:
                arrays += 1
                _take_tracks(msg, track_of, seen_at)
    except (BagError, McapError, RuntimeError, EOFError, IndexError, struct.error) as exc:
        # what the reader or the CDR decoder raise on data they cannot read
        raise ValueError(f'{bag}: cannot read: {type(exc).__name__}: {exc}') from None
    for msg in tracks or ():
        arrays += 1
        _take_tracks(msg, track_of, seen_at)
    if arrays == 0:
        raise ValueError(f'{bag}: no {TRACKS} messages: nothing to draw')
    notes = [f'the bag is damaged: {p}' for p in reader.problems] if reader.damaged else []
    positions = {**seen_at, **station_of}
    keys = [k for k in track_of if k[0] in positions]
    if len(keys) < len(track_of):
        notes.append(
            f'{len(track_of) - len(keys)} unassigned detection(s) of sensors not in '
            f'{LAYOUT} left out'
        )
    if not keys:
        raise ValueError(f'{bag}: the tracks hold no detection')
    ids = sorted({t for k in keys if (t := track_of[k]) is not None})
    dense = {t: i for i, t in enumerate(ids)}
    labels = np.array([dense.get(track_of[k], UNASSIGNED) for k in keys], np.int64)
    target = None
    if truth_of:
        targets = sorted({t for t in truth_of.values() if t is not None})
        number = {t: i for i, t in enumerate(targets)}
        number[None] = FALSE_ALARM
        target = np.array([number[truth_of[k]] if k in truth_of else NO_TRUTH for k in keys])
        missing = int(np.count_nonzero(target == NO_TRUTH))
        if missing:
            notes.append(f'{missing} detection(s) without ground truth: not judged')
    stamps = np.array([k[2] for k in keys], np.int64) / NS_PER_S
    if network is not None:
        index = {int(s): i for i, s in enumerate(network.station_ids)}
        station = [index.get(k[0], -1) for k in keys]
        return on_route(network, route, station, stamps, labels, target, str(bag), notes)
    stations = station_of or seen_at
    return PlotInput(
        position=np.array([positions[k[0]] for k in keys]),
        stamp=stamps,
        labels=labels,
        target=target,
        stations=np.array(sorted(stations.values())),
        source=str(bag),
        notes=notes,
    )


def _network(msg):
    """The road network of a recorded layout (a decoded message of any definition)."""
    from mlkm_ros.network_conversions import msg_to_network

    return msg_to_network(_Fields(msg))


class _Fields:
    """A decoded message whose fields an older definition lacks read as empty."""

    def __init__(self, msg) -> None:
        self._msg = msg

    def __getattr__(self, name: str):
        return getattr(self._msg, name, ())


def _take_tracks(msg, track_of: dict, seen_at: dict) -> None:
    """Record which track (or none) each detection of one TrackArray belongs to now."""
    episode = int(msg.episode_id) if int(msg.mode) == 0 else 0  # MODE_EPISODES
    for track in msg.tracks:
        key = (episode, int(track.track_id))
        n = len(track.sensor_ids)
        lanes = getattr(track, 'lanes', None) or [-1] * n
        for sid, stamp, lane, pos in zip(
            track.sensor_ids, track.stamps, lanes, track.positions, strict=False
        ):
            track_of[(int(sid), int(lane), _ns(stamp))] = key
            seen_at[int(sid)] = float(pos)
    lanes = getattr(msg, 'unassigned_lanes', None) or [-1] * len(msg.unassigned_sensor_ids)
    for sid, stamp, lane in zip(msg.unassigned_sensor_ids, msg.unassigned_stamps, lanes):
        track_of[(int(sid), int(lane), _ns(stamp))] = None
