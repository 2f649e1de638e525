"""The stop flag that SIGINT and SIGTERM set (mlkm_ros.lifecycle.StopRequest)."""

import signal
import threading

from mlkm_ros.lifecycle import StopRequest


def test_a_signal_inside_the_handler_of_the_first_returns_at_once() -> None:
    """Python runs a signal's handler between two bytecodes of the main thread, also while an
    earlier handler holds the event's lock: the second handler must not wait for that lock
    (it would wait forever, one more nested handler per further signal)."""
    stop = StopRequest()
    done = threading.Event()

    def second_signal_while_the_first_holds_the_lock() -> None:
        stop.handler(signal.SIGINT, None)
        with stop._event._cond:  # where the first handler is when the next signal lands
            stop.handler(signal.SIGINT, None)
            stop.handler(signal.SIGTERM, None)
        done.set()

    thread = threading.Thread(target=second_signal_while_the_first_holds_the_lock, daemon=True)
    thread.start()
    assert done.wait(10.0), 'the nested handler waited for the lock its own thread holds'
    assert stop.requested
    assert stop.signum == signal.SIGINT


def test_cleared_the_next_signal_counts_again() -> None:
    stop = StopRequest()
    stop.handler(signal.SIGTERM, None)
    stop.clear()
    assert not stop.requested and stop.signum is None
    stop.handler(signal.SIGINT, None)
    assert stop.requested and stop.signum == signal.SIGINT


class _Refused(Exception):
    pass


def _refused_factory():
    raise _Refused('netconvert failed (exit -2)')


def test_a_refusal_after_a_stop_request_ends_the_start_up_with_0(capsys) -> None:
    """Ctrl-C reaches the whole process group: a helper the constructor runs dies of it and
    the constructor raises what would otherwise be a refusal; the node ends with 0."""
    from mlkm_ros import lifecycle

    refusals = [((_Refused,), 'error: ', 2)]
    lifecycle.STOP.clear()
    try:
        assert lifecycle.start_node('probe', _refused_factory, refusals) == (None, 2)
        assert 'probe: error: netconvert failed' in capsys.readouterr().err
        lifecycle.STOP.request(signal.SIGINT)
        assert lifecycle.start_node('probe', _refused_factory, refusals) == (None, 0)
        assert 'probe: stopped during start-up (netconvert failed' in capsys.readouterr().err
    finally:
        lifecycle.STOP.clear()
