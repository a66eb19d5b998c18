"""Ctrl-C and SIGTERM during a run's frame loops: raised between frames, never inside a lock.

Python raises ``KeyboardInterrupt`` (and the CLI's SIGTERM handler :class:`Terminated`)
wherever the main thread happens to be -- also just after it took the lock of a queue or a
condition and before the ``with`` that would release it is entered. The run's worker
threads (prefetch, ordered writer) then wait on that lock for ever, and so does the main
thread when it drains them: the run hangs instead of stopping (a CI run's SIGTERM'd run
did not exit within 120 s). Inside :func:`deferred_interrupts` such a signal is recorded
and raised by :func:`raise_if_interrupted` at the loops' safe points (between frames), or
when the scope ends; a second signal raises at once, the escape hatch when a frame hangs.

Only signals whose handler raises (SIGINT with Python's default handler, SIGTERM with
:func:`raise_terminated`) are deferred; a handler someone else installed is left alone,
and so is every thread but the main one (signals reach the main thread only).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["Terminated", "deferred_interrupts", "raise_if_interrupted", "raise_terminated"]


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a robot's process manager, ``docker stop``) handled like Ctrl-C."""


def raise_terminated(signum, frame) -> None:
    """A SIGTERM handler that raises :class:`Terminated` (the CLI installs it)."""
    raise Terminated()


def _exception_for(signum: int) -> KeyboardInterrupt:
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


class _Scope:
    """The signals recorded while a :func:`deferred_interrupts` scope is open."""

    def __init__(self) -> None:
        self.pending: KeyboardInterrupt | None = None

    def handle(self, signum, frame) -> None:
        if self.pending is not None:  # the second signal: at once (and the first is spent)
            self.pending = None
            raise _exception_for(signum)
        self.pending = _exception_for(signum)

    def raise_pending(self) -> None:
        exc, self.pending = self.pending, None
        if exc is not None:
            raise exc


_active: _Scope | None = None  # the open scope (signals are process-wide and reach the main thread only)


def _deferrable(handler) -> bool:
    return handler is signal.default_int_handler or handler is raise_terminated


@contextmanager
def deferred_interrupts() -> Iterator[None]:
    """Within: SIGINT/SIGTERM that would raise are recorded and raised by
    :func:`raise_if_interrupted` (or when the scope ends without another error).
    Nested scopes and non-main threads pass through unchanged."""
    global _active
    if _active is not None or threading.current_thread() is not threading.main_thread():
        yield
        return
    scope = _Scope()
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    changed = {s: h for s, h in previous.items() if _deferrable(h)}
    _active = scope
    for s in changed:
        signal.signal(s, scope.handle)
    try:
        yield
    finally:
        for s, h in changed.items():
            signal.signal(s, h)
        _active = None
    scope.raise_pending()  # reached only when the body ended without an error of its own


def raise_if_interrupted() -> None:
    """Raise the signal recorded by the open :func:`deferred_interrupts` scope, if any
    (``KeyboardInterrupt`` for SIGINT, :class:`Terminated` for SIGTERM)."""
    if _active is not None:
        _active.raise_pending()
