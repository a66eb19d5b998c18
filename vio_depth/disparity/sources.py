"""The disparity sources that read or simulate maps: files and SIMULATED-from-ground-truth.

(The third kind, a network run on each image, is :class:`~vio_depth.disparity.model.ModelDisparity`.)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vio_core.checks import check_array
from vio_core.errors import InputError, SequenceFormatError
from vio_core.npyfile import load_array

from ..frame import Frame
from .base import DisparityKind, check_disparity
from .densify import GtDisparitySettings, simulate_gt_disparity
from .simulation import DisparitySimulation, disparity_preset, simulate_disparity


class FileDisparity:
    """``<folder>/<image stem>.npy`` per frame: float (H, W) affine-invariant disparity.

    Args:
        folder: the folder (a user's ``--disparity-dir``, or the sequence's own).
        required: a missing file raises :class:`SequenceFormatError` (the sequence declared
            it); when False a missing file gives None, i.e. status ``no_disparity``.
    """

    kind = DisparityKind.FILES

    def __init__(self, folder, *, required: bool = False):
        self.folder = Path(folder)
        self.required = required
        if not self.folder.is_dir():
            raise InputError(f"{self.folder}: disparity folder does not exist")

    def path_for(self, frame: Frame) -> Path:
        return self.folder / f"{frame.stem}.npy"

    def missing_reason(self, frame: Frame) -> str:
        """Why there is no map for ``frame``: its file, named (status ``no_disparity``)."""
        return f"disparity file {self.path_for(frame)} not found (one <image stem>.npy per frame)"

    def __call__(self, frame: Frame) -> np.ndarray | None:
        path = self.path_for(frame)
        if not path.is_file():
            if self.required:
                raise SequenceFormatError(path, "disparity file not found")
            return None  # reported as status no_disparity for this frame
        return check_disparity(load_array(path, "disparity"), frame, str(path))


class SimulatedDisparitySource:
    """SIMULATES a Depth Anything disparity from each frame's ground-truth depth.

    Everything evaluated with it must be labelled SIMULATED (``kind`` says so).

    Args:
        seed: non-negative; frame ``k``'s map is seeded with ``(seed, frame.index)``.
        model: the simulation's parameters (default: its "default" preset).
        densify: None for dense, exact ground truth (the rendered samples: the model is
            applied to the depth map as is); :class:`GtDisparitySettings` for sparse or holey
            real ground truth (KITTI LiDAR, Kinect), which is densified first and is NaN
            outside the valid region (:func:`~vio_depth.disparity.densify.simulate_gt_disparity`).

    Raises:
        InputError: negative or non-integer seed.
    """

    kind = DisparityKind.SIMULATED

    def __init__(self, seed: int = 0, model: DisparitySimulation | None = None,
                 densify: GtDisparitySettings | None = None):
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise InputError(f"simulated disparity seed must be a non-negative integer, got {seed!r}")
        self.seed = int(seed)
        self.densify = densify
        if densify is not None and model is not None and model != densify.model:
            raise InputError("give the simulation model once: in `model` or in `densify.model`")
        self.model = densify.model if densify is not None else (disparity_preset("default") if model is None else model)

    def simulate(self, frame: Frame):
        """The frame's :class:`~vio_depth.disparity.simulation.SimulatedDisparity` (with the
        true per-frame alpha, beta), or None when it has no (valid) ground-truth depth."""
        gt = frame.gt_depth()
        if gt is None:
            return None
        cam = frame.camera
        check_array(f"ground-truth depth of frame {frame.stem}", gt, (cam.height, cam.width))
        if self.densify is None:
            return simulate_disparity(gt, self.seed, frame.index, self.model)
        return simulate_gt_disparity(gt, self.seed, frame.index, self.densify)

    def __call__(self, frame: Frame) -> np.ndarray | None:
        sim = self.simulate(frame)
        if sim is None:
            return None
        return check_disparity(sim.disparity, frame, f"simulated disparity of frame {frame.stem}")
