"""A shard's hand-off messages: offers and continuations go out at once; a message that only
moves the shard's times goes out once they moved ``TIMES_STEP`` or the shard caught up."""

from __future__ import annotations

from mlkm_assoc.stream_shard import TIMES_STEP, ShardPublisher, ShardRole


def row(sensor: int, stamp: float) -> tuple:
    """A tracker-state row: sensor id, stamp [ns], speed, position, lane, length."""
    return (sensor, round(stamp * 1e9), 30.0, 100.0, 0, 4.5)


def test_a_shard_publishes_a_handoff_only_when_it_has_news() -> None:
    assert TIMES_STEP == 1.0  # the stamps below are chosen around it
    # shard 0 of 2: no margin; its station 20 is the next shard's margin
    pub = ShardPublisher(ShardRole(0, 2, (), (20,), 60.0), lambda **message: message)
    first = pub.commit([(5, row(10, 1.0))], 1.0, 2.0, run=1)
    assert first is not None and first['offers'] == [] and first['settled_until_ns'] == 1e9
    assert pub.commit([(5, row(10, 1.5))], 1.5, 2.5, run=1) is None  # moved 0.5 s only
    offered = pub.commit([(5, row(20, 1.8))], 1.8, 2.8, run=1)  # an offer goes out at once
    assert [(t, [r[0] for r in rows]) for t, _, rows in offered['offers']] == [(5, [20])]
    moved = pub.commit([], 2.9, 3.0, run=1)  # 1.1 s past the last message's times
    assert moved is not None and moved['committed_until_ns'] == 2.9e9
    caught_up = pub.commit([], 3.0, 3.0, run=1)  # settled everything it took
    assert caught_up is not None and caught_up['newest_ns'] == 3e9
    assert pub.commit([], 3.2, 3.2, run=1) is None  # still caught up, moved 0.2 s
    assert pub.commit([], 3.2, 3.5, run=1) is not None  # behind the newest stamp again
    assert pub.counts['handoff_offers'] == 1


def test_a_continuation_goes_out_at_once() -> None:
    # shard 1 of 2: station 20 is its margin, 30 its own
    pub = ShardPublisher(ShardRole(1, 2, ((20, 0),), (), 60.0), lambda **message: message)
    assert pub.take([], 0.5, run=1) is not None  # the first message
    held = pub.commit([(3, row(20, 1.0)), (3, row(30, 1.4))], 1.4, 1.4, run=1)
    assert held is not None and held['continuations'] == []  # caught up: news
    assert pub.take([], 0.9, run=1) is None  # the offer of its margin detection is not in
    taken = pub.take([(7, (20, 0, round(1e9), 30.0))], 1.1, run=1)
    assert taken['continuations'] == [(7, 3)]
