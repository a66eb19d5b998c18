"""The landmark window in a worker process: :class:`ProcessWindow`.

A keyframe update (triangulation over the window, Levenberg-Marquardt over poses and
landmarks, the poses' marginals, marginalisation) costs several frames' worth of time,
and gtsam holds Python's GIL while it runs, so a thread cannot run it beside the next
frames. The peers that keep up with a camera (VINS-Mono, ORB-SLAM) split tracking from
mapping; here the window lives in a **worker process**: :meth:`ProcessWindow.submit` sends
it a keyframe and returns at once, the caller goes on tracking frames against the last
:class:`~.snapshot.WindowSnapshot`, and :meth:`ProcessWindow.result` takes the update and
the refined window's snapshot over (waiting for them if they are not ready).

The worker is a fresh interpreter (``spawn``: safe beside OpenCV's and torch's threads); it
starts once (about a second) and serves every window of its owner (:meth:`reset` starts
a new, empty one). The motion factor source is built in the worker by a picklable
``motion_factory`` (e.g. ``functools.partial(ImuFactors, imu, settings)``); a source fed by
streamed samples gets each keyframe's samples with it (``update_samples``). Failures come
back as the caller would have seen them inline: a :class:`~vio_core.errors.NumericalError`
(the window is unusable) or another :class:`~vio_core.errors.VioDepthError` is raised again
in the caller; anything else, or a worker that died, raises
:class:`~vio_core.errors.WorkerError` with the worker's traceback.
"""

from __future__ import annotations

import multiprocessing as mp
import traceback
import weakref
from typing import Any, Callable

from vio_core.errors import InputError, NumericalError, VioDepthError, WorkerError

from .settings import LandmarkSettings
from .snapshot import WindowSnapshot
from .types import KeyframeInput, WindowUpdate
from .window import LandmarkWindow


def _serve(conn) -> None:
    """The worker's loop: one reply per request, until "stop" or the pipe closes."""
    window = None
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        except Exception:  # a request that does not unpickle here (e.g. a class it cannot import)
            conn.send(("crash", traceback.format_exc()))
            continue
        if msg[0] == "stop":
            return
        try:
            if msg[0] == "ping":
                reply = ("ok", None, None)
            elif msg[0] == "new":
                _, settings, factory = msg
                window = LandmarkWindow(settings, None if factory is None else factory())
                reply = ("ok", None, window.snapshot())
            else:  # "add"
                _, kf, initial, samples = msg
                if window is None:
                    raise InputError("landmarks: the window worker has no window (reset first)")
                if samples is not None:
                    window.motion_factors.update_samples(samples)
                update = window.add_keyframe(kf, initial)
                reply = ("ok", update, window.snapshot() if update.ok else None)
        except NumericalError as exc:
            window = None  # unusable: the caller resets
            reply = ("numerical", str(exc))
        except VioDepthError as exc:
            reply = ("raise", exc, traceback.format_exc())
        except Exception:  # a bug: its traceback goes to the caller
            reply = ("crash", traceback.format_exc())
        conn.send(reply)


def _stop(proc, conn) -> None:
    try:
        conn.send(("stop",))
    except (OSError, ValueError):
        pass
    proc.join(timeout=2.0)
    if proc.is_alive():
        proc.terminate()
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
        self._pending = False
        self._finalizer = weakref.finalize(self, _stop, self._proc, self._conn)

    @property
    def pending(self) -> bool:
        """A keyframe was submitted and its result not taken yet."""
        return self._pending

    def ready(self) -> bool:
        """The pending keyframe's result has arrived (never blocks)."""
        return self._pending and self._conn.poll()

    def ping(self) -> None:
        """Wait until the worker answers (it has started and imported what it needs)."""
        if self._pending:
            raise InputError("landmarks: a keyframe is being inserted (take its result first)")
        self._send(("ping",))
        self._reply()

    def reset(self, settings: LandmarkSettings, motion_factory: Callable[[], Any] | None = None) -> WindowSnapshot:
        """Start a new, empty window in the worker (a pending result is discarded).

        Args:
            settings: the window's :class:`LandmarkSettings` (resolved).
            motion_factory: picklable callable returning the window's
                :class:`~.motion.MotionFactorSource`, or None for pose priors.

        Returns:
            The empty window's snapshot.
        """
        if self._pending:
            try:
                self.result()
            except VioDepthError:
                pass  # the old window is dropped anyway
        self._send(("new", settings, motion_factory))
        return self._reply()[1]

    def submit(self, kf: KeyframeInput, initial: Any | None = None, samples: Any | None = None) -> None:
        """Send a keyframe (:meth:`LandmarkWindow.add_keyframe`'s arguments; ``samples``: the
        motion source's new samples, or None); returns at once."""
        if self._pending:
            raise InputError("landmarks: a keyframe is already being inserted (take its result first)")
        self._send(("add", kf, initial, samples))
        self._pending = True

    def result(self) -> tuple[WindowUpdate, WindowSnapshot | None]:
        """The pending keyframe's :class:`~.types.WindowUpdate` and the window's snapshot
        after it (None when the window refused the keyframe: unchanged); waits for them.

        Raises:
            NumericalError: the update failed numerically (the window is unusable: reset).
            VioDepthError: what the window raised.
            WorkerError: the worker failed unexpectedly or died.
        """
        if not self._pending:
            raise InputError("landmarks: no keyframe is being inserted")
        self._pending = False
        return self._reply()

    def insert(self, kf: KeyframeInput, initial: Any | None = None,
               samples: Any | None = None) -> tuple[WindowUpdate, WindowSnapshot | None]:
        """:meth:`submit` and :meth:`result` (a synchronous insertion)."""
        self.submit(kf, initial, samples)
        return self.result()

    def close(self) -> None:
        """Stop the worker (also done when the object is collected or at exit)."""
        self._finalizer()

    # ------------------------------------------------------------------ pipe
    def _send(self, msg) -> None:
        try:
            self._conn.send(msg)
        except (OSError, ValueError) as exc:
            raise WorkerError(f"landmarks: the window worker is gone ({self._exit()})") from exc

    def _reply(self):
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
