"""HeldPublisher: the tracks wait for their subscribers, then go out in order."""

import threading

import pytest

from mlkm_ros.held_publisher import HeldPublisher


class FakePublisher:
    """The two calls HeldPublisher makes of an rclpy Publisher."""

    def __init__(self) -> None:
        self.subscribers = 0
        self.sent: list[int] = []

    def get_subscription_count(self) -> int:
        return self.subscribers

    def publish(self, msg: int) -> None:
        self.sent.append(msg)


def test_held_until_the_subscribers_match_then_in_order_and_never_again() -> None:
    pub = FakePublisher()
    holds: list[tuple[int, int]] = []
    held = HeldPublisher(pub, 2, lambda n, count: holds.append((n, count)))
    held.publish(1)
    pub.subscribers = 1
    held.publish(2)
    assert pub.sent == [] and held.held == 2 and not held.released
    assert holds == [(1, 0), (2, 1)]
    assert not held.poll()
    pub.subscribers = 2
    assert held.poll()
    assert pub.sent == [1, 2] and held.held == 0 and held.released
    pub.subscribers = 0  # a subscriber leaving later does not hold the topic again
    held.publish(3)
    assert pub.sent == [1, 2, 3]


def test_the_next_publish_releases_the_held_ones_before_itself() -> None:
    pub = FakePublisher()
    held = HeldPublisher(pub, 1)
    held.publish('a')
    pub.subscribers = 1
    held.publish('b')
    assert pub.sent == ['a', 'b']


def test_zero_publishes_at_once_and_a_negative_count_is_refused() -> None:
    pub = FakePublisher()
    held = HeldPublisher(pub, 0)
    held.publish(7)
    assert pub.sent == [7] and held.released
    with pytest.raises(ValueError, match='least'):
        HeldPublisher(pub, -1)


def test_publishers_in_two_threads_lose_nothing() -> None:
    pub = FakePublisher()
    held = HeldPublisher(pub, 1)
    threads = [
        threading.Thread(target=lambda k=k: [held.publish((k, i)) for i in range(500)])
        for k in range(2)
    ]
    for t in threads:
        t.start()
    pub.subscribers = 1
    for t in threads:
        t.join()
    held.poll()
    assert sorted(pub.sent) == sorted((k, i) for k in range(2) for i in range(500))
    for k in range(2):
        assert [i for kk, i in pub.sent if kk == k] == list(range(500))


class RefusingPublisher(FakePublisher):
    """Refuses its first ``refusals`` publishes as a full Fast DDS KEEP_ALL writer does."""

    def __init__(self, refusals: int) -> None:
        super().__init__()
        self.refusals = refusals

    def publish(self, msg: int) -> None:
        from rclpy._rclpy_pybind11 import RCLError

        if self.refusals > 0:
            self.refusals -= 1
            raise RCLError('Failed to publish: cannot publish data')
        super().publish(msg)

    def wait_for_all_acked(self, timeout) -> bool:  # noqa: ANN001 - rclpy Duration
        return True


class Up:
    def ok(self) -> bool:
        return True


def test_over_a_reliable_publisher_a_full_writer_loses_nothing() -> None:
    from mlkm_ros.publishing import ReliablePublisher

    pub = RefusingPublisher(refusals=4)
    pub.subscribers = 1
    reliable = ReliablePublisher(pub, Up(), sleep=lambda _s: None)
    held = HeldPublisher(reliable, 1)
    for i in range(5):
        held.publish(i)
    assert pub.sent == [0, 1, 2, 3, 4] and reliable.retries == 4


def test_poll_never_waits_on_a_publish_that_waits_for_its_readers() -> None:
    class Blocking(FakePublisher):
        def __init__(self) -> None:
            super().__init__()
            self.entered, self.go = threading.Event(), threading.Event()

        def publish(self, msg: int) -> None:
            self.entered.set()
            assert self.go.wait(10.0)
            super().publish(msg)

    pub = Blocking()
    pub.subscribers = 1
    held = HeldPublisher(pub, 1)
    assert held.poll()  # released
    thread = threading.Thread(target=held.publish, args=(1,))
    thread.start()
    assert pub.entered.wait(10.0)
    assert held.poll() and held.held == 0  # returns while the publish still waits
    pub.go.set()
    thread.join(10.0)
    assert pub.sent == [1]
