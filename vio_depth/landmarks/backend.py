"""The landmark window in a worker process: :class:`ProcessWindow`.

A keyframe update (triangulation over the window, Levenberg-Marquardt over poses and
landmarks, the poses' marginals, marginalisation) costs several frames' worth of time,
and gtsam holds Python's GIL while it runs, so a thread cannot run it beside the next
frames. The peers that keep up with a camera (VINS-Mono, ORB-SLAM) split tracking from
mapping; here the window lives in a **worker process**: :meth:`ProcessWindow.submit` sends
it a keyframe and returns at once, the caller goes on tracking frames against the last
:class:`~.snapshot.WindowSnapshot`, and :meth:`ProcessWindow.result` takes the update and
the refined window's snapshot over (waiting for them if they are not ready). Keyframes
submitted before the earlier ones' results are taken queue in the worker and are inserted
in order, one result each (a reader thread there takes requests off the pipe as they come).

The worker is a fresh interpreter (``spawn``: safe beside OpenCV's and torch's threads); it
starts once (about a second) and serves every window of its owner (:meth:`reset` starts
a new, empty one). The motion factor source is built in the worker by a picklable
``motion_factory`` (e.g. ``functools.partial(ImuFactors, imu, settings)``); a source fed by
streamed samples gets each keyframe's samples with it (``update_samples``). Failures come
back as the caller would have seen them inline: a :class:`~vio_core.errors.NumericalError`
(the window is unusable) or another :class:`~vio_core.errors.VioDepthError` is raised again
in the caller; anything else, or a worker that died, raises
:class:`~vio_core.errors.WorkerError` with the worker's traceback.

The worker also runs other long computations of its owner beside the frames
(:meth:`ProcessWindow.submit_call`: a picklable function and its arguments, e.g. a VIO's
dynamic initialisation attempt), one at a time and never while a keyframe is pending; their
failures come back the same way.
"""

from __future__ import annotations

import multiprocessing as mp
import queue
import threading
import traceback
import weakref
from dataclasses import replace
from typing import Any, Callable, Sequence

from vio_core.errors import InputError, NumericalError, VioDepthError, WorkerError

from .settings import LandmarkSettings
from .snapshot import WindowSnapshot
from .types import KeyframeInput, WindowUpdate
from .window import LandmarkWindow


def _inbox(conn, inbox: queue.SimpleQueue) -> None:
    """The worker's reader thread: every request into ``inbox`` as it arrives, so that the owner's
    sends never wait for the window's work (the owner may send the next keyframe while the worker
    sends a snapshot: a worker blocked in that send releases the GIL, and this thread drains
    the pipe -- with one thread both sends would wait for each other)."""
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            inbox.put(("stop",))
            return
        except Exception:  # a request that does not unpickle here (e.g. a class it cannot import)
            inbox.put(("unreadable", traceback.format_exc()))
            continue
        inbox.put(msg)
        if msg[0] == "stop":
            return


def _serve(conn) -> None:
    """The worker's loop: one reply per request, in order, until "stop" or the pipe closes."""
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    threading.Thread(target=_inbox, args=(conn, inbox), daemon=True, name="vio-depth-window-inbox").start()
    window = None
    while True:
        msg = inbox.get()
        if msg[0] == "stop":
            return
        if msg[0] == "unreadable":
            try:
                conn.send(("crash", msg[1]))
            except (BrokenPipeError, OSError):
                return
            continue
        try:
            if msg[0] == "ping":
                reply = ("ok", None, None)
            elif msg[0] == "call":  # a function of the owner's (the window is left as it is)
                reply = ("ok", msg[1](*msg[2]), None)
            elif msg[0] == "new":
                _, settings, factory = msg
                window = LandmarkWindow(settings, None if factory is None else factory())
                reply = ("ok", None, None)
            else:  # "add": keyframes in order, up to the first one the window refuses
                if window is None:
                    raise InputError("landmarks: the window worker has no window (reset first)")
                updates = []
                for kf, initial, samples in msg[1]:
                    if samples is not None:
                        window.motion_factors.update_samples(samples)
                    # a queued keyframe was matched with the window as its owner saw it, and with
                    # the keyframes queued before it: one that the window refused or has
                    # marginalised since is no longer there to match (as inline, not matched)
                    ids = set(window.keyframe_ids)
                    kf = replace(kf, matches=tuple(m for m in kf.matches if m.keyframe in ids))
                    updates.append(window.add_keyframe(kf, initial))
                    if not updates[-1].ok:
                        break
                changed = len(updates) > 1 or updates[0].ok
                reply = ("ok", tuple(updates), window.snapshot() if changed else None)
        except NumericalError as exc:
            if msg[0] != "call":
                window = None  # unusable: the caller resets
            reply = ("numerical", str(exc))
        except VioDepthError as exc:
            reply = ("raise", exc, traceback.format_exc())
        except Exception:  # a bug: its traceback goes to the caller
            reply = ("crash", traceback.format_exc())
        try:
            conn.send(reply)
        except (BrokenPipeError, OSError):  # the owner is gone (collected mid-request): stop quietly
            return


#: seconds :meth:`ProcessWindow.close` waits for the worker's own exit before terminating it
#: (an interpreter unloading gtsam on a loaded 2-core machine took more than 2 s once)
_EXIT_WAIT_S = 15.0


def _stop(proc, conn) -> None:
    """Ask the worker to stop and close the pipe (a worker blocked sending a reply then fails and
    exits); no waiting: run when the object is collected, which may be in the middle of a frame
    (joining a worker's exit cost ~0.1 s there). :meth:`ProcessWindow.close` waits."""
    try:
        conn.send(("stop",))
    except (OSError, ValueError):
        pass
    conn.close()


class ProcessWindow:
    """A :class:`~.window.LandmarkWindow` in a worker process (module docstring).

    Args:
        start_method: multiprocessing start method of the worker (``"spawn"``).
    """

    def __init__(self, start_method: str = "spawn"):
        ctx = mp.get_context(start_method)
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(child,), daemon=True, name="vio-depth-window")
        self._proc.start()
        child.close()
        self._pending = 0  # keyframe submissions whose replies are owed, in order
        self._calling = False  # a submit_call's reply is owed
        # replies owed by the worker before the next one waited for: resets' (short; an error in
        # one is raised, nothing else is read from them)
        self._owed = 0
        self._finalizer = weakref.finalize(self, _stop, self._proc, self._conn)

    @property
    def alive(self) -> bool:
        """The worker process runs (False after :meth:`close`, or when it died)."""
        return self._proc.is_alive()

    @property
    def pending(self) -> int:
        """Keyframe submissions whose results were not taken yet (0: none)."""
        return self._pending

    def ready(self) -> bool:
        """The oldest pending keyframe submission's result has arrived (never blocks; an owed reset's failure
        that has arrived is raised, as by :meth:`ping`)."""
        while self._owed and self._conn.poll():
            self._owed_reply()
        return bool(self._pending) and not self._owed and self._conn.poll()

    @property
    def calling(self) -> bool:
        """A :meth:`submit_call` was made and its result not taken yet."""
        return self._calling

    def call_ready(self) -> bool:
        """The pending call's result has arrived (never blocks; as :meth:`ready`)."""
        while self._owed and self._conn.poll():
            self._owed_reply()
        return self._calling and not self._owed and self._conn.poll()

    def submit_call(self, fn: Callable[..., Any], *args) -> None:
        """Run ``fn(*args)`` in the worker (both picklable; ``fn`` a module-level function);
        returns at once. :meth:`call_result` takes the result. One at a time, and not while a
        keyframe is pending (:meth:`discard` drops one first)."""
        if self._pending or self._calling:
            raise InputError("landmarks: the window worker is busy (take its result first)")
        self._send(("call", fn, args))
        self._calling = True

    def call_result(self) -> Any:
        """What the pending :meth:`submit_call` returned; waits for it.

        Raises:
            NumericalError, VioDepthError: what the function raised.
            WorkerError: it failed unexpectedly, or the worker died.
        """
        if not self._calling:
            raise InputError("landmarks: no call is pending")
        self._calling = False
        return self._reply()[0]

    def discard(self) -> None:
        """Wait for every pending keyframe's or call's result and drop them (failures too,
        but a :class:`WorkerError`); nothing pending: returns at once."""
        while self._pending or self._calling:
            try:
                if self._pending:
                    self.result()
                else:
                    self.call_result()
            except WorkerError:
                raise
            except VioDepthError:
                pass  # what is dropped failed: nothing depends on it

    def ping(self) -> None:
        """Wait until the worker answers (it has started and imported what it needs).

        Raises:
            WorkerError, VioDepthError: a reset since the last wait failed in the worker.
        """
        if self._pending or self._calling:
            raise InputError("landmarks: a keyframe is being inserted (take its result first)")
        self._send(("ping",))
        self._reply()

    def reset(self, settings: LandmarkSettings, motion_factory: Callable[[], Any] | None = None) -> None:
        """Start a new, empty window in the worker; returns at once, without waiting for the
        worker (a worker still starting keeps the caller waiting only at the first result) --
        except for a pending result, which is waited for and discarded. The new window's snapshot is
        :meth:`WindowSnapshot.empty <.snapshot.WindowSnapshot.empty>`; a failure to build it
        (e.g. a ``motion_factory`` the worker cannot import) is raised by the next call that
        waits for the worker (:meth:`result`, :meth:`insert`, :meth:`ping`).

        Args:
            settings: the window's :class:`LandmarkSettings` (resolved).
            motion_factory: picklable callable returning the window's
                :class:`~.motion.MotionFactorSource`, or None for pose priors.
        """
        # a pending reply is read (and dropped) first: a snapshot may not fit in the pipe's
        # buffer, and a worker blocked sending it while we send would never read (deadlock)
        self.discard()
        self._send(("new", settings, motion_factory))
        self._owed += 1  # a short reply: the worker sends it and reads on

    def submit(self, kf: KeyframeInput, initial: Any | None = None, samples: Any | None = None) -> None:
        """Send a keyframe (:meth:`LandmarkWindow.add_keyframe`'s arguments; ``samples``: the
        motion source's new samples, or None); returns at once."""
        self.submit_batch([(kf, initial, samples)])

    def submit_batch(self, keyframes: Sequence[tuple[KeyframeInput, Any | None, Any | None]]) -> None:
        """Send keyframes ``(kf, initial, samples)`` (as :meth:`submit`'s) to be inserted in
        order, e.g. the keyframes of an initialisation; the worker stops at the first one the
        window refuses. Returns at once. Submissions queue in the worker: each gets its own
        result, in order (a keyframe's matches with a queued keyframe the window then refused
        or marginalised are dropped there)."""
        if self._calling:
            raise InputError("landmarks: the window worker is running a call (take its result first)")
        if not keyframes:
            raise InputError("landmarks: no keyframe to insert")
        self._send(("add", list(keyframes)))
        self._pending += 1

    def result(self) -> tuple[WindowUpdate, WindowSnapshot | None]:
        """The oldest pending submission's :class:`~.types.WindowUpdate` (of a batch: its last, which is
        the refused one if any) and the window's snapshot after it (None when the window is
        unchanged: it refused the only keyframe); waits for them.

        Raises:
            NumericalError: the update failed numerically (the window is unusable: reset).
            VioDepthError: what the window raised.
            WorkerError: the worker failed unexpectedly or died.
        """
        updates, snapshot = self.batch_result()
        return updates[-1], snapshot

    def batch_result(self) -> tuple[tuple[WindowUpdate, ...], WindowSnapshot | None]:
        """:meth:`result` with every inserted keyframe's update, in order (a batch stops at
        the first refused keyframe: that one is the last)."""
        if not self._pending:
            raise InputError("landmarks: no keyframe is being inserted")
        self._pending -= 1
        return self._reply()

    def insert(self, kf: KeyframeInput, initial: Any | None = None,
               samples: Any | None = None) -> tuple[WindowUpdate, WindowSnapshot | None]:
        """:meth:`submit` and :meth:`result` (a synchronous insertion)."""
        self.submit(kf, initial, samples)
        return self.result()

    def close(self) -> None:
        """Stop the worker and wait for it to exit (it is also told to stop, without waiting,
        when the object is collected; a daemon, it ends with the interpreter at the latest)."""
        self._finalizer()
        self._proc.join(timeout=_EXIT_WAIT_S)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=2.0)

    # ------------------------------------------------------------------ pipe
    def _send(self, msg) -> None:
        try:
            self._conn.send(msg)
        except (OSError, ValueError) as exc:
            raise WorkerError(f"landmarks: the window worker is gone ({self._exit()})") from exc

    def _reply(self):
        """The reply to the last request, after the replies owed before it; an owed reset's
        failure is raised once that reply is read too (the pipe stays in step)."""
        error = None
        while self._owed:
            try:
                self._owed_reply()
            except VioDepthError as exc:
                error = error or exc
        reply = self._receive()
        if error is not None:
            raise error
        return reply

    def _owed_reply(self) -> None:
        self._owed -= 1
        self._receive()

    def _receive(self):
        try:
            msg = self._conn.recv()
        except (EOFError, OSError) as exc:
            raise WorkerError(f"landmarks: the window worker died ({self._exit()}); it is a fresh interpreter "
                              "(multiprocessing 'spawn') that imports the main script again: a script must build "
                              "its pipeline under `if __name__ == '__main__':`") from exc
        if msg[0] == "ok":
            return msg[1], msg[2]
        if msg[0] == "numerical":
            raise NumericalError(msg[1])
        if msg[0] == "raise":
            exc = msg[1]
            exc.add_note(f"(raised in the window worker)\n{msg[2]}")
            raise exc
        raise WorkerError(f"landmarks: the window worker failed:\n{msg[1]}")

    def _exit(self) -> str:
        self._proc.join(timeout=0.5)
        code = self._proc.exitcode
        return "still running" if code is None else f"exit code {code}"
