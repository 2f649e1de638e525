"""A bag's TrackArrays to the diagram's labels: each detection belongs to the track (or the
unassigned list) that carried it last; tracks of different episodes never merge."""

from types import SimpleNamespace as Msg

from mlkm_assoc.timespace_bag import _take_tracks

EPISODES, STREAM = 0, 1
S = 10**9  # ns per s: detections are keyed by their stamp in ns


def t(sec):
    return Msg(sec=sec, nanosec=0)


def track(track_id, sensors, secs, lanes=None):
    return Msg(
        track_id=track_id,
        sensor_ids=sensors,
        stamps=[t(s) for s in secs],
        positions=[100.0 * s for s in sensors],
        lanes=lanes if lanes is not None else [0] * len(sensors),
    )


def array(mode, episode, tracks, unassigned=()):
    return Msg(
        mode=mode,
        episode_id=episode,
        tracks=tracks,
        unassigned_sensor_ids=[s for s, _ in unassigned],
        unassigned_stamps=[t(sec) for _, sec in unassigned],
        unassigned_lanes=[0] * len(unassigned),
    )


def labels(messages):
    track_of, seen_at = {}, {}
    for m in messages:
        _take_tracks(m, track_of, seen_at)
    return track_of, seen_at


def test_a_detection_belongs_to_the_track_that_carried_it_last():
    first = array(STREAM, 0, [track(7, [0, 1], [10, 14])], unassigned=[(2, 20)])
    # the stream revises: track 8 takes sensor 1's detection and the unassigned one
    later = array(STREAM, 0, [track(7, [0], [10]), track(8, [1, 2], [14, 20])])
    track_of, seen_at = labels([first, later])
    assert track_of == {(0, 0, 10 * S): (0, 7), (1, 0, 14 * S): (0, 8), (2, 0, 20 * S): (0, 8)}
    assert seen_at == {0: 0.0, 1: 100.0, 2: 200.0}
    # and back: the last publication unassigns it
    track_of, _ = labels([first, later, array(STREAM, 0, [], unassigned=[(2, 20)])])
    assert track_of[(2, 0, 20 * S)] is None


def test_episodes_keep_their_track_ids_apart():
    track_of, _ = labels(
        [array(EPISODES, 0, [track(1, [0], [5])]), array(EPISODES, 1, [track(1, [0], [500])])]
    )
    assert set(track_of.values()) == {(0, 1), (1, 1)}


def test_a_track_of_an_older_definition_without_lanes_is_read_with_lane_unknown():
    old = Msg(track_id=3, sensor_ids=[0], stamps=[t(1)], positions=[0.0])
    old_array = Msg(
        mode=EPISODES, episode_id=2, tracks=[old], unassigned_sensor_ids=[], unassigned_stamps=[]
    )
    track_of, _ = labels([old_array])
    assert track_of == {(0, -1, 1 * S): (2, 3)}
