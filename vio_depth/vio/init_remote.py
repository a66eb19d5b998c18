"""The dynamic initialisation attempts in the landmark window's worker process.

With the window in a worker (``VioSettings.backend`` kind ``process``), a dynamic attempt
(:func:`~.dynamic_start.attempt_dynamic`: two bundle adjustments and the IMU alignment,
~0.4 s on the ASL sample) would stall the frame that completes the candidates.
:class:`RemoteInitializer` offers the frames to the :class:`~.initializer.Initializer` with
the attempt deferred, sends the attempt to the worker
(:meth:`~vio_depth.landmarks.ProcessWindow.submit_call`) when its conditions hold, and goes on
offering frames -- they keep initialising and collecting candidates -- until its outcome is
taken over, ``init_lag_frames`` frames later (waiting for it then if it is not ready; as soon
as it is ready with ``apply_when_ready``). One attempt at a time. A success starts from the
attempt's candidates, with every frame offered since the first of them (those after its newest
keyframe too) to be posed from its keyframes; a refusal is handled as in the frame
(:meth:`~.initializer.Initializer.refuse`: a failed reconstruction drops the attempt's oldest
candidate, if it is still the oldest), and the next frame whose conditions hold tries again.
A static start, checked in every frame, drops an attempt in flight. The window of a start
taken over here is due ``start_lag_frames`` after the attempt's submission (not after its
take-over: the first tracked frame is the one it would be with the attempt in its own frame). The worker's failures are
raised as the attempt would have raised them in the frame (:mod:`vio_depth.landmarks.backend`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from matchers import Features
from vio_core.camera import Camera

from ..landmarks import ProcessWindow, WindowBackendSettings
from .dynamic_start import attempt_dynamic
from .initializer import Candidate, Initializer, InitKind, InitResult


def catch_up_candidates(candidates: list[Candidate], res: InitResult, n: int) -> list[Candidate]:
    """The ``candidates`` collected after a dynamic initialisation's newest keyframe while its
    attempt ran in the worker process: up to ``n`` of them (``catch_up_keyframes``), spread evenly
    in time up to the newest, to join the start's window (without them the first keyframe tracked
    would be matched across every frame of the attempt's and the window's lags: ~20 frames, and on
    a street drive ~20 common landmarks decided the scale)."""
    last = res.keyframes[-1]
    later = [c for c in candidates if c.frame_id > last.frame_id]
    if n == 0 or not later or res.kind != InitKind.DYNAMIC:
        return []
    times = np.array([c.t for c in later])
    targets = last.t + (times[-1] - last.t) * np.arange(1, n + 1) / n
    picks = sorted({int(np.argmin(np.abs(times - g))) for g in targets})
    return [later[i] for i in picks]


@dataclass
class _InFlight:
    at: int  # frames offered before it was submitted, itself included
    candidates: tuple[Candidate, ...]
    frames: list[tuple[int, float]]  # (id, t) of the frames offered since its oldest candidate


class RemoteInitializer:
    """:class:`~.initializer.Initializer`'s per-frame interface with the dynamic attempt in
    the window's worker (module docstring).

    Args:
        initializer: collects the candidates and runs the static start.
        backend: the window's worker process.
        settings: ``init_lag_frames`` and ``apply_when_ready``.
    """

    def __init__(self, initializer: Initializer, backend: ProcessWindow, settings: WindowBackendSettings):
        self.initializer = initializer
        self.backend = backend
        self.settings = settings
        self._flight: _InFlight | None = None
        self._frames = 0
        #: attempts sent to the worker (diagnostics)
        self.submitted = 0
        #: frames between the submission of the last start's attempt and its take-over (0 for a
        #: static start): the start's window, built in the worker after it, is due that much sooner
        self.landed_after = 0

    @property
    def in_flight(self) -> bool:
        """An attempt is running in the worker (its outcome not taken over yet)."""
        return self._flight is not None

    def reset(self) -> None:
        """Start over (an attempt in flight is waited for and dropped)."""
        self._drop()
        self.initializer.reset()

    def candidate_times(self) -> list[float]:
        """Seconds of the candidates waiting and of those of an attempt in flight."""
        times = self.initializer.candidate_times()
        if self._flight is not None:
            times += [c.t for c in self._flight.candidates]
        return times

    def process(self, frame_id: int, t: float, camera: Camera, features: Features) -> InitResult:
        """Offer the next frame: an attempt's outcome when it is due here and succeeded (the
        frame itself then follows the start), else this frame's own result."""
        self._frames += 1
        if self._flight is not None:
            res = self._land()
            if res is not None and res.ok:
                return res
        if self._flight is not None:
            self._flight.frames.append((int(frame_id), float(t)))
        res = self.initializer.process(frame_id, t, camera, features, defer=True)
        if res.ok:  # a static start
            self._drop()
            self.landed_after = 0
            return res
        if res.attempt and self._flight is None:
            ini = self.initializer
            self.backend.discard()  # a lost window's keyframe may still be pending there
            self.backend.submit_call(attempt_dynamic, ini.attempt_inputs(imu_span=True))
            self._flight = _InFlight(self._frames, ini.candidates(), ini.offered_frames())
            self.submitted += 1
            if self.settings.init_lag_frames == 0:
                return self._land()
        return res

    def finish(self) -> InitResult | None:
        """The outcome of the attempt in flight, waited for now (the sequence ended before it was
        due: :meth:`~.estimator.VioEstimator.finish`), or None when none is in flight."""
        return None if self._flight is None else self._land(now=True)

    def _land(self, now: bool = False) -> InitResult | None:
        """The attempt's outcome when due (module docstring) or ``now``, else None."""
        f, b = self._flight, self.settings
        if not (now or self._frames - f.at >= b.init_lag_frames or (b.apply_when_ready and self.backend.call_ready())):
            return None
        self._flight = None
        self.landed_after = self._frames - f.at
        res = self.initializer.attempt_result(self.backend.call_result(), f.candidates, f.frames)
        if not res.ok:  # a reconstruction failure may come from the oldest candidate: drop it
            self.initializer.refuse(res.reason, drop_oldest=res.alignment is None, oldest=f.candidates[0].frame_id)
        return res

    def _drop(self) -> None:
        if self._flight is not None:
            self._flight = None
            self.backend.discard()
