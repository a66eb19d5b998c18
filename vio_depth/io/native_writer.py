"""Writing the native vio-depth sequence format (the reader is :mod:`vio_depth.io.native`)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array, check_image, check_transform
from vio_core.errors import InputError

from ..disparity import DisparityKind, DisparitySpec
from ..frame import ImuData
from .depth_png import DEPTH_PNG_SCALE, write_depth_png
from .native import FORMAT_TAG, FORMAT_VERSION
from .tables import write_tum_trajectory


def write_imu_txt(path, t, gyro, accel) -> None:
    """Write ``t: (M,)`` s, ``gyro: (M, 3)`` rad/s, ``accel: (M, 3)`` m/s^2 as imu.txt."""
    t = check_array("t", t, (None,), finite=True)
    gyro = check_array("gyro", gyro, (len(t), 3), finite=True)
    accel = check_array("accel", accel, (len(t), 3), finite=True)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("# timestamp gx gy gz ax ay az (s, rad/s, m/s^2; IMU frame)\n")
        for ti, g, a in zip(t, gyro, accel):
            fh.write(f"{ti:.6f} {g[0]:.9f} {g[1]:.9f} {g[2]:.9f} {a[0]:.9f} {a[1]:.9f} {a[2]:.9f}\n")


# json.dumps(indent=2) puts every list item on its own line; raw newlines never occur inside
# JSON strings, so requiring them keeps string values untouched
_NUMBER_LIST = re.compile(r"\[\n\s*((?:-?[0-9.eE+-]+,\n\s*)*-?[0-9.eE+-]+)\n\s*\]")


def _dump_json(data: dict) -> str:
    """Indented JSON with innermost lists of numbers on one line (matrix rows stay readable)."""
    text = json.dumps(data, indent=2)
    return _NUMBER_LIST.sub(lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]", text)

class NativeSequenceWriter:
    """Stream frames into a native sequence folder; :meth:`close` writes the text files.

    Images are written as they are added (nothing is kept in memory but timestamps and
    poses). Usage::

        with NativeSequenceWriter(root, "demo", camera) as w:
            w.set_imu(imu)                                   # optional
            w.set_disparity(DisparitySpec.simulated(seed=1))     # optional
            for t, image, T_w_c, depth in frames:
                w.add_frame(t, image, T_w_c, depth=depth)
    """

    def __init__(self, root, name: str, camera: Camera, *, image_ext: str = ".jpg", jpeg_quality: int = 90,
                 metadata: dict | None = None, overwrite: bool = False):
        self.root = Path(root)
        if (self.root / "sequence.json").exists() and not overwrite:
            raise InputError(f"{self.root}: already holds a sequence (pass overwrite=True to replace it)")
        if image_ext not in (".jpg", ".png"):
            raise InputError(f"image_ext must be '.jpg' or '.png', got {image_ext!r}")
        self.name = name
        self.camera = camera
        self.image_ext = image_ext
        self.jpeg_quality = int(jpeg_quality)
        self.metadata = dict(metadata or {})
        self._t: list[float] = []
        self._T: list[np.ndarray] = []
        self._stems: list[str] = []
        self._has_depth: bool | None = None
        self._imu: ImuData | None = None
        self._imu_simulation: dict | None = None
        self._disparity: DisparitySpec | None = None
        (self.root / "images").mkdir(parents=True, exist_ok=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()

    def set_imu(self, imu: ImuData, simulation: dict | None = None) -> None:
        """IMU samples to write to imu.txt (``simulation``: optional free-form JSON notes)."""
        self._imu = imu
        self._imu_simulation = simulation

    def set_disparity(self, source: DisparitySpec) -> None:
        """Declare the disparity source; "files" disparities are then passed to :meth:`add_frame`."""
        self._disparity = source

    def add_frame(self, timestamp: float, image, T_w_c, *, depth=None, disparity=None, stem: str | None = None) -> str:
        """Write one frame.

        Args:
            timestamp: seconds, greater than the previous frame's.
            image: (H, W, 3) uint8 RGB (or (H, W) grey) of the camera's size.
            T_w_c: (4, 4) camera-to-world pose, metres, or None: then for every frame, and the
                sequence needs IMU samples (:meth:`set_imu`; no poses.txt is written).
            depth: optional (H, W) metres GT depth (NaN / <= 0 = invalid); all frames or none.
            disparity: (H, W) float disparity, required iff the disparity source is "files".
            stem: file stem (default: 6-digit frame number).

        Returns:
            the stem used.
        """
        image = np.asarray(image)
        if image.ndim == 2:
            image = np.repeat(image[:, :, None], 3, axis=2)
        image = check_image("image", image, channels=3)
        if image.dtype != np.uint8:
            raise InputError(f"image: expected uint8, got {image.dtype}")
        if image.shape[:2] != (self.camera.height, self.camera.width):
            raise InputError(f"image: size {image.shape[1]}x{image.shape[0]} differs from the camera's "
                             f"{self.camera.width}x{self.camera.height}")
        T_w_c = None if T_w_c is None else check_transform("T_w_c", T_w_c)
        if self._T and (self._T[-1] is None) != (T_w_c is None):
            raise InputError("give a pose for every frame or for none")
        if self._t and not timestamp > self._t[-1]:
            raise InputError(f"timestamps must increase: {timestamp} after {self._t[-1]}")
        stem = f"{len(self._t):06d}" if stem is None else str(stem)
        if stem in self._stems or not stem or any(c.isspace() for c in stem) or "/" in stem:
            raise InputError(f"stem {stem!r} is empty, repeated or contains spaces / slashes")
        if self._has_depth is None:
            self._has_depth = depth is not None
        elif self._has_depth != (depth is not None):
            raise InputError("give a depth map for every frame or for none")
        if (self._disparity is not None and self._disparity.kind == DisparityKind.FILES) != (disparity is not None):
            raise InputError("pass disparity to add_frame exactly when the disparity source is 'files'")

        image_path = self.root / "images" / f"{stem}{self.image_ext}"
        params = [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality] if self.image_ext == ".jpg" else [cv2.IMWRITE_PNG_COMPRESSION, 9]
        if not cv2.imwrite(str(image_path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR), params):
            raise InputError(f"{image_path}: cannot write image")
        if depth is not None:
            depth = check_array("depth", depth, (self.camera.height, self.camera.width))
            (self.root / "depth").mkdir(exist_ok=True)
            write_depth_png(self.root / "depth" / f"{stem}.png", depth)
        if disparity is not None:
            disparity = check_array("disparity", disparity, (self.camera.height, self.camera.width))
            folder = self.root / self._disparity.folder
            folder.mkdir(parents=True, exist_ok=True)
            np.save(folder / f"{stem}.npy", disparity.astype(np.float32))
        self._t.append(float(timestamp))
        self._T.append(None if T_w_c is None else T_w_c.copy())
        self._stems.append(stem)
        return stem

    def close(self) -> Path:
        """Write frames.txt, poses.txt, imu.txt and sequence.json; returns the folder."""
        if not self._t:
            raise InputError("no frames were added")
        if self._disparity is not None and self._disparity.kind == DisparityKind.SIMULATED and not self._has_depth:
            raise InputError("simulated disparity needs GT depth for every frame")
        with open(self.root / "frames.txt", "w", encoding="utf-8") as fh:
            fh.write("# timestamp image_path\n")
            for t, stem in zip(self._t, self._stems):
                fh.write(f"{t:.6f} images/{stem}{self.image_ext}\n")
        posed = self._T[0] is not None
        if not posed and self._imu is None:
            raise InputError("a sequence without poses needs IMU samples (set_imu)")
        if posed:
            write_tum_trajectory(self.root / "poses.txt", np.asarray(self._t), np.stack(self._T))
        c = self.camera
        meta = {
            "format": FORMAT_TAG,
            "version": FORMAT_VERSION,
            "name": self.name,
            "camera": {"width": c.width, "height": c.height, "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                       "dist": list(c.dist)},
            "frames": "frames.txt",
        }
        if posed:
            meta["poses"] = "poses.txt"
        if c.model != "radtan":  # absent = radtan: files of radial-tangential cameras stay unchanged
            meta["camera"]["model"] = c.model
        if self._has_depth:
            meta["depth"] = {"folder": "depth", "scale": DEPTH_PNG_SCALE}
        if self._imu is not None:
            imu = self._imu
            write_imu_txt(self.root / "imu.txt", imu.t, imu.gyro, imu.accel)
            rate = 1.0 / float(np.median(np.diff(imu.t))) if len(imu.t) > 1 else 0.0
            meta["imu"] = {
                "file": "imu.txt",
                "T_c_i": np.asarray(imu.T_c_i, dtype=float).tolist(),
                "rate_hz": round(rate, 6),
                "gyro_noise_density": imu.gyro_noise,
                "accel_noise_density": imu.accel_noise,
                "gyro_bias_random_walk": imu.gyro_bias_walk,
                "accel_bias_random_walk": imu.accel_bias_walk,
                "gravity_w": [float(g) for g in imu.gravity_w],
            }
            if self._imu_simulation is not None:
                meta["imu"]["simulation"] = self._imu_simulation
        if self._disparity is not None:
            meta["disparity"] = self._disparity.to_json()
        if self.metadata:
            meta["metadata"] = self.metadata
        with open(self.root / "sequence.json", "w", encoding="utf-8") as fh:
            fh.write(_dump_json(meta) + "\n")
        return self.root


def write_native_sequence(root, name: str, camera: Camera, timestamps: Iterable[float], images: Iterable,
                          T_w_c: Iterable, *, depths: Iterable | None = None, imu: ImuData | None = None,
                          disparity: DisparitySpec | None = None, disparities: Iterable | None = None,
                          stems: Iterable[str] | None = None, image_ext: str = ".jpg", jpeg_quality: int = 90,
                          metadata: dict | None = None, overwrite: bool = False) -> Path:
    """Write a whole native sequence in one call (iterables are consumed lazily, in step).

    Args:
        timestamps: N seconds. images: N (H, W, 3) uint8 RGB. T_w_c: N (4, 4) camera-to-world.
        depths: optional N (H, W) metres GT depth maps.
        imu: optional IMU samples. disparity: optional :class:`DisparitySpec`;
        disparities: the N (H, W) arrays when ``disparity`` is :meth:`DisparitySpec.files`.
        stems: optional N file stems (default 000000, 000001, ...).

    Returns:
        the sequence folder.
    """
    if disparities is not None and disparity is None:
        disparity = DisparitySpec.files()
    w = NativeSequenceWriter(root, name, camera, image_ext=image_ext, jpeg_quality=jpeg_quality,
                             metadata=metadata, overwrite=overwrite)
    if imu is not None:
        w.set_imu(imu)
    if disparity is not None:
        w.set_disparity(disparity)
    timestamps = list(timestamps)
    n = len(timestamps)
    it_img, it_T = iter(images), iter(T_w_c)
    it_depth = iter(depths) if depths is not None else None
    it_disp = iter(disparities) if disparities is not None else None
    it_stem = iter(stems) if stems is not None else None
    for i in range(n):
        try:
            image, T = next(it_img), next(it_T)
            depth = next(it_depth) if it_depth is not None else None
            disp = next(it_disp) if it_disp is not None else None
            stem = next(it_stem) if it_stem is not None else None
        except StopIteration:
            raise InputError(f"fewer images/poses/depths/disparities/stems than the {n} timestamps") from None
        w.add_frame(timestamps[i], image, T, depth=depth, disparity=disp, stem=stem)
    return w.close()
