"""Back-pressure for reliable KEEP_ALL publishers: as fast as delivery allows, nothing lost.

A reliable KEEP_ALL writer keeps every sample until each matched reader acknowledged it. When a
reader falls behind, the writer's history fills up; Fast DDS then blocks ``publish`` for its
``max_blocking_time`` and rclpy raises ``RCLError: Failed to publish: cannot publish data``.
Every publisher the project writes to such a topic goes through :class:`ReliablePublisher`:

* flow control: after ``window`` messages without a confirmed acknowledgement it waits until
  every reader acknowledged everything, so the unacknowledged backlog stays bounded and a slow
  subscriber slows the publisher down instead of breaking it;
* when the middleware still refuses a message it waits for acknowledgements (growing waits)
  and tries again, for up to ``deadline`` seconds without any progress; only then it raises
  :class:`PublishTimeout` with the topic and the time waited;
* a stop request (``stop`` event, or the ROS context shut down by Ctrl-C) ends the waits at
  once: :meth:`ReliablePublisher.publish` then returns False instead of raising.

Counters (``published``, ``retries``, ``window_waits``, ``waited``) tell how often the
publisher had to wait.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from rclpy._rclpy_pybind11 import RCLError
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.publisher import Publisher

from mlkm_ros.held_publisher import HeldPublisher

#: Messages published without a confirmed acknowledgement before the publisher waits for one.
#: Well below Fast DDS's KEEP_ALL history limit (5000 samples), so that the writer never fills
#: up because of the publisher alone.
DEFAULT_WINDOW = 1000
#: [s] how long a publisher waits for readers that make no progress before it gives up.
DEFAULT_DEADLINE = 300.0
#: [s] granularity of the waits (how fast a stop request is noticed).
_WAIT_STEP = 0.2
#: [s] first and longest pause between two attempts of a refused publish.
_BACKOFF_MIN = 0.01
_BACKOFF_MAX = 0.5


class PublishTimeout(RuntimeError):
    """The readers acknowledged nothing for the whole deadline; the message was not sent."""


class ReliablePublisher:
    """Wraps one rclpy publisher: :meth:`publish` never drops and never raises on a full writer.

    ``context`` is the context of the publisher's node (Ctrl-C shuts it down); ``stop`` is an
    optional event of the caller that interrupts every wait.
    """

    def __init__(
        self,
        publisher: Publisher,
        context: Context,
        stop: threading.Event | None = None,
        *,
        window: int = DEFAULT_WINDOW,
        deadline: float = DEFAULT_DEADLINE,
        sleep: Callable[[float], Any] | None = None,
    ) -> None:
        if window < 1:
            raise ValueError('window must be >= 1')
        if deadline <= 0:
            raise ValueError('deadline must be > 0')
        self._publisher = publisher
        self._context = context
        self._stop = stop if stop is not None else threading.Event()
        self._window = window
        self._deadline = deadline
        self._sleep = sleep if sleep is not None else self._stop.wait
        self._unconfirmed = 0  # messages published since the last complete acknowledgement
        self.published = 0
        self.retries = 0  # publishes the middleware refused and that were tried again
        self.window_waits = 0  # flow-control waits for acknowledgements
        self.waited = 0.0  # [s] total time spent waiting for readers

    @property
    def publisher(self) -> Publisher:
        return self._publisher

    @property
    def topic_name(self) -> str:
        return self._publisher.topic_name

    def get_subscription_count(self) -> int:
        """Matched subscriptions of the wrapped publisher (as rclpy's ``Publisher``)."""
        return self._publisher.get_subscription_count()

    def _stopped(self) -> bool:
        return self._stop.is_set() or not self._context.ok()

    def publish(self, msg: Any) -> bool:
        """Publish ``msg``; False if a stop request came first (then it may not be sent)."""
        if self._unconfirmed >= self._window:
            self.window_waits += 1
            if not self.wait_acked(self._deadline, raise_on_timeout=True):
                return False
        start = None
        backoff = _BACKOFF_MIN
        while True:
            if self._stopped():
                return False
            try:
                self._publisher.publish(msg)
            except RCLError as exc:
                if self._stopped():
                    return False  # the context went away under us (Ctrl-C): not an error
                now = time.monotonic()
                if start is None:
                    start = now
                elif now - start >= self._deadline:
                    raise PublishTimeout(
                        f'{self.topic_name}: the middleware refused a message for '
                        f'{now - start:.0f} s: no subscriber acknowledged anything ({exc})'
                    ) from None
                self.retries += 1
                self._let_readers_catch_up(backoff)
                backoff = min(2 * backoff, _BACKOFF_MAX)
                continue
            self.published += 1
            self._unconfirmed += 1
            return True

    def _let_readers_catch_up(self, pause: float) -> None:
        began = time.monotonic()
        try:
            if self._publisher.wait_for_all_acked(Duration(seconds=pause)):
                self._unconfirmed = 0
        except RCLError:
            self._sleep(pause)
        self.waited += time.monotonic() - began

    def wait_acked(self, timeout: float, raise_on_timeout: bool = False) -> bool:
        """Wait until every matched reader acknowledged every message, at most ``timeout`` s.

        True when they did; False on timeout or stop request. With ``raise_on_timeout`` a
        timeout raises :class:`PublishTimeout` instead.
        """
        began = time.monotonic()
        try:
            while not self._stopped():
                remaining = timeout - (time.monotonic() - began)
                if remaining <= 0:
                    if raise_on_timeout:
                        raise PublishTimeout(
                            f'{self.topic_name}: subscribers acknowledged nothing for '
                            f'{timeout:g} s'
                        )
                    return False
                step = Duration(seconds=min(_WAIT_STEP, remaining))
                try:
                    acked = self._publisher.wait_for_all_acked(step)
                except RCLError:
                    if self._stopped():
                        return False
                    raise
                if acked:
                    self._unconfirmed = 0
                    return True
            return False
        finally:
            self.waited += time.monotonic() - began

    def stats(self) -> dict[str, float]:
        return {
            'published': self.published,
            'retries': self.retries,
            'window_waits': self.window_waits,
            'waited': round(self.waited, 3),
        }


def tracks_publisher(
    node: Node, least: int, on_hold: Callable[[int, int], None] | None = None
) -> HeldPublisher:
    """The node's /mlkm/tracks publisher: held until ``least`` subscribers matched
    (:class:`~mlkm_ros.held_publisher.HeldPublisher`), then reliable (a subscriber that falls
    behind slows the publishing thread down, it never makes a TrackArray fail and get lost);
    ``.publisher`` is the :class:`ReliablePublisher` with its counters."""
    from mlkm_ros import qos
    from road_sensor_msgs.msg import TrackArray

    writer = node.create_publisher(TrackArray, qos.TRACKS_TOPIC, qos.TRACKS_QOS)
    return HeldPublisher(ReliablePublisher(writer, node.context), least, on_hold)


def wait_all_acked(publishers: list[ReliablePublisher], timeout: float) -> bool:
    """Wait (sharing one ``timeout`` [s]) until every publisher's readers acknowledged all."""
    deadline = time.monotonic() + timeout
    ok = True
    for pub in publishers:
        ok = pub.wait_acked(max(0.0, deadline - time.monotonic())) and ok
    return ok


def total_stats(publishers: list[ReliablePublisher]) -> dict[str, float]:
    """The counters of several publishers, summed."""
    out: dict[str, float] = {'published': 0, 'retries': 0, 'window_waits': 0, 'waited': 0.0}
    for pub in publishers:
        for key, value in pub.stats().items():
            out[key] += value
    out['waited'] = round(out['waited'], 3)
    return out
