"""Ctrl-C / SIGTERM inside a run's frame loops are raised at safe points, never inside a lock."""

import signal
import threading

import pytest

from vio_depth.run import Terminated, deferred_interrupts, raise_if_interrupted, raise_terminated


@pytest.fixture
def raising_handlers():
    """SIGINT with Python's default handler and SIGTERM with the CLI's, restored afterwards."""
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, raise_terminated)
    yield
    for s, h in before.items():
        signal.signal(s, h)


def test_a_signal_inside_a_lock_is_raised_at_the_next_safe_point(raising_handlers):
    lock = threading.Lock()
    with pytest.raises(Terminated):
        with deferred_interrupts():
            with lock:
                signal.raise_signal(signal.SIGTERM)  # the handler runs here, in the main thread
                assert lock.locked()  # ...and raised nothing: the lock's `with` is left normally
            assert not lock.locked()
            raise_if_interrupted()
            pytest.fail("the recorded SIGTERM was not raised")
    assert not lock.locked()


def test_sigint_is_deferred_as_keyboard_interrupt_and_not_as_terminated(raising_handlers):
    with deferred_interrupts():
        signal.raise_signal(signal.SIGINT)
        with pytest.raises(KeyboardInterrupt) as caught:
            raise_if_interrupted()
    assert type(caught.value) is KeyboardInterrupt
    raise_if_interrupted()  # raised once: nothing is left pending


def test_a_second_signal_raises_at_once(raising_handlers):
    with deferred_interrupts():
        signal.raise_signal(signal.SIGINT)
        with pytest.raises(Terminated):
            signal.raise_signal(signal.SIGTERM)  # the escape hatch when a frame hangs


def test_a_signal_after_the_last_safe_point_is_raised_when_the_scope_ends(raising_handlers):
    with pytest.raises(Terminated):
        with deferred_interrupts():
            signal.raise_signal(signal.SIGTERM)
    assert signal.getsignal(signal.SIGTERM) is raise_terminated  # handlers restored
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with pytest.raises(Terminated):  # outside the scope: raised where it lands, as before
        signal.raise_signal(signal.SIGTERM)


def test_the_body_s_own_error_wins_over_a_pending_signal(raising_handlers):
    with pytest.raises(ValueError):
        with deferred_interrupts():
            signal.raise_signal(signal.SIGTERM)
            raise ValueError("the frame failed")


def test_a_handler_someone_else_installed_is_left_alone(raising_handlers):
    seen = []
    signal.signal(signal.SIGTERM, lambda signum, frame: seen.append(signum))
    with deferred_interrupts():
        signal.raise_signal(signal.SIGTERM)
        raise_if_interrupted()  # nothing was deferred
    assert seen == [signal.SIGTERM]


def test_nested_scopes_and_other_threads_pass_through(raising_handlers):
    outcome = []

    def elsewhere():
        with deferred_interrupts():  # not the main thread: no handler is touched
            outcome.append(signal.getsignal(signal.SIGTERM) is raise_terminated)

    t = threading.Thread(target=elsewhere)
    t.start()
    t.join()
    assert outcome == [True]
    with pytest.raises(Terminated):
        with deferred_interrupts():
            with deferred_interrupts():
                signal.raise_signal(signal.SIGTERM)
                raise_if_interrupted()
