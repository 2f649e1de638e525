"""A publisher that holds its first messages until the topic has its expected subscribers.

DDS discovers the graph asynchronously: a subscriber started before a node can still be
matched with the node's publisher only after the node published its first messages, and a
volatile topic does not deliver those late. A node whose own graph (a scorer, a recorder, a
user's tracker) must see every message holds them here until its publisher counts
``least`` subscribers, then publishes them in order and every later message at once.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any


class HeldPublisher:
    """``publish`` through ``publisher`` once it counts ``least`` matched subscribers (0: at
    once); until then the messages are held, in order, and :meth:`poll` (from a timer) or the
    next ``publish`` releases them. Released once, it never holds again: a subscriber that
    leaves later does not stop the topic. Thread-safe; ``on_hold(held, count)`` is called at
    every message held (the node logs it, throttled). ``publisher`` may block (a
    :class:`~mlkm_ros.publishing.ReliablePublisher` waiting for a slow reader): once released,
    no lock is held around it, so :meth:`poll` from a timer never waits on it."""

    def __init__(
        self,
        publisher: Any,
        least: int,
        on_hold: Callable[[int, int], None] | None = None,
    ) -> None:
        if least < 0:
            raise ValueError(f'least must be >= 0, got {least}')
        self._publisher = publisher
        self._least = least
        self._on_hold = on_hold
        self._lock = threading.Lock()
        self._held: list[Any] | None = [] if least > 0 else None

    @property
    def publisher(self) -> Any:
        """The publisher the messages go through."""
        return self._publisher

    @property
    def least(self) -> int:
        """Subscribers awaited before the first message goes out."""
        return self._least

    @property
    def held(self) -> int:
        """Messages waiting for the subscribers."""
        held = self._held
        return 0 if held is None else len(held)

    @property
    def released(self) -> bool:
        return self._held is None

    def publish(self, msg: Any) -> None:
        if self._held is None:  # released: the publisher's own back-pressure, no lock held
            self._publisher.publish(msg)
            return
        with self._lock:
            if self._held is not None and not self._release():
                self._held.append(msg)
                if self._on_hold is not None:
                    self._on_hold(len(self._held), self._publisher.get_subscription_count())
                return
        self._publisher.publish(msg)

    def poll(self) -> bool:
        """Release the held messages if the subscribers are there; True once released."""
        if self._held is None:
            return True
        with self._lock:
            return self._held is None or self._release()

    def _release(self) -> bool:
        if self._publisher.get_subscription_count() < self._least:
            return False
        for msg in self._held or []:
            self._publisher.publish(msg)
        self._held = None  # only now: a publish in another thread waits for the held ones
        return True
