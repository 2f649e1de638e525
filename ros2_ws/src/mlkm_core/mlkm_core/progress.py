"""How far a long computation is, for whoever shows it (the CLI's bars); the core never prints.

A caller that wants to follow a computation runs it inside ``reporting(callback)``: the
callback gets the fraction done, in [0, 1], never decreasing. The computation marks its parts
with ``stage(start, end)``, the share of the enclosing part that each spans (from measured
shares of the time), and reports within a part with ``advance(done, total)``; a part whose
inner steps do not measure it (``detail=False``) reports only its end. Without a listener
(the nodes, the benchmarks) every call is a context-variable lookup and nothing else.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field

#: Smallest increase of the fraction passed on to the callback (the last report, 1, always is).
MIN_STEP = 0.001


@dataclass
class _Listener:
    callback: Callable[[float], None]
    last: float = field(default=0.0)

    def report(self, fraction: float) -> None:
        fraction = min(max(fraction, 0.0), 1.0)
        if fraction >= self.last + MIN_STEP or (fraction == 1.0 and self.last < 1.0):
            self.last = fraction
            self.callback(fraction)


@dataclass(frozen=True)
class _Span:
    listener: _Listener
    lo: float  # fraction of the whole where this part starts
    hi: float  # ... and ends
    detail: bool = True  # whether advance() inside is passed on


_SPAN: ContextVar[_Span | None] = ContextVar('mlkm_progress', default=None)


@contextmanager
def reporting(callback: Callable[[float], None]) -> Iterator[None]:
    """Pass the fraction done of what runs inside to ``callback(fraction)``."""
    token = _SPAN.set(_Span(_Listener(callback), 0.0, 1.0))
    try:
        yield
    finally:
        _SPAN.reset(token)


@contextmanager
def stage(start: float, end: float, detail: bool = True) -> Iterator[None]:
    """A part of the enclosing one, from its fraction ``start`` to ``end``; its end is
    reported when it finishes. ``detail=False``: ``advance`` inside it is not passed on."""
    outer = _SPAN.get()
    if outer is None:
        yield
        return
    width = outer.hi - outer.lo
    inner = _Span(
        outer.listener, outer.lo + width * start, outer.lo + width * end, outer.detail and detail
    )
    token = _SPAN.set(inner)
    try:
        yield
    finally:
        _SPAN.reset(token)
    inner.listener.report(inner.hi)


def advance(done: float, total: float) -> None:
    """``done`` of ``total`` steps of the current part are done."""
    span = _SPAN.get()
    if span is None or not span.detail or total <= 0:
        return
    span.listener.report(span.lo + (span.hi - span.lo) * min(done / total, 1.0))
