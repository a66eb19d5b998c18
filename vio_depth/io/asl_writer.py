"""Write sequences in the EuRoC / TUM-VI ASL layout (read by :mod:`vio_depth.io.asl`).

The body frame of a written sequence is the IMU frame (as in EuRoC): ``imu0/sensor.yaml``
gets ``T_BS = T_B_C T_c_i`` and the ground truth is the pose of the IMU, with
``state_groundtruth_estimate0/sensor.yaml`` carrying the same ``T_BS`` (so the reader maps
it back to the IMU exactly). YAML files follow EuRoC's style (``%YAML:1.0`` first line,
``T_BS`` as ``rows/cols/data``). Usage::

    with AslWriter(root, camera, T_B_C) as w:
        w.set_imu(imu)                                    # optional
        w.set_ground_truth(t, T_w_i, velocity_w, ...)     # optional
        for t, image in frames:
            w.add_frame(t, image)
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.checks import check_array, check_image, check_transform
from vio_core.errors import InputError

from ..frame import ImuData

#: vio_core.Camera model -> ASL distortion_model name
_ASL_DISTORTION = {"radtan": "radial-tangential", "equidistant": "equidistant"}


def seconds_to_ns(t) -> np.ndarray:
    """(N,) seconds -> (N,) int64 nanoseconds (rounded)."""
    return np.round(check_array("t", np.atleast_1d(t), (None,), finite=True) * 1e9).astype(np.int64)


def _yaml_float(v: float) -> str:
    """A float YAML 1.1 reads as a float (``repr`` keeps a decimal point: ``2e-05`` -> ``2.0e-05``)."""
    text = repr(float(v))
    if "e" in text and "." not in text:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}.0e{exponent}"
    return text


def _matrix_yaml(T: np.ndarray) -> str:
    rows = [", ".join(_yaml_float(v) for v in r) for r in T]
    return "T_BS:\n  cols: 4\n  rows: 4\n  data: [" + ",\n         ".join(rows) + "]\n"


def _list_yaml(values) -> str:
    return "[" + ", ".join(str(v) if isinstance(v, (int, np.integer)) else _yaml_float(v) for v in values) + "]"


def write_sensor_yaml(path, sensor_type: str, comment: str, T_BS, fields: dict) -> None:
    """EuRoC-style ``sensor.yaml``: header, ``T_BS`` (4, 4) sensor-to-body, then ``fields``
    (numbers, strings or lists of numbers), one ``key: value`` per line."""
    T_BS = check_transform("T_BS", T_BS)
    out = ["%YAML:1.0", f"sensor_type: {sensor_type}", f"comment: {comment}", "", _matrix_yaml(T_BS)]
    for key, value in fields.items():
        if isinstance(value, (list, tuple, np.ndarray)):
            value = _list_yaml(value)
        elif isinstance(value, float):
            value = _yaml_float(value)
        out.append(f"{key}: {value}")
    Path(path).write_text("\n".join(out) + "\n", encoding="utf-8")


def _write_table(path: Path, header: str, t_ns: np.ndarray, values: np.ndarray) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(header + "\n")
        for t, row in zip(t_ns, values):
            fh.write(f"{int(t)}," + ",".join(f"{v:.12g}" for v in row) + "\n")


class AslWriter:
    """Stream frames into an ASL folder ``root/mav0/...``; :meth:`close` writes the tables.

    Args:
        root: output folder (``mav0/`` is created in it); must not already hold ``mav0``
            unless ``overwrite``.
        camera: intrinsics and distortion of the images.
        T_B_C: (4, 4) camera-to-body transform.
        grey: write 8-bit grey PNGs (as EuRoC) instead of colour.
        rate_hz: camera rate written to ``cam0/sensor.yaml`` (informative).
        time_offset_ns: added (exactly, in integers) to every timestamp after its conversion
            from seconds, so that times near 0 s can be written on a real clock without
            float rounding.
    """

    def __init__(self, root, camera: Camera, T_B_C, *, grey: bool = True, rate_hz: float = 20.0,
                 time_offset_ns: int = 0, overwrite: bool = False):
        self.root = Path(root)
        self.mav0 = self.root / "mav0"
        if self.mav0.exists() and not overwrite:
            raise InputError(f"{self.root}: already holds mav0/ (pass overwrite=True to replace it)")
        self.camera = camera
        self.T_B_C = check_transform("T_B_C", T_B_C)
        self.grey = grey
        self.rate_hz = float(rate_hz)
        self.time_offset_ns = int(time_offset_ns)
        self._t_ns: list[int] = []
        self._imu: ImuData | None = None
        self._gt: tuple | None = None
        (self.mav0 / "cam0" / "data").mkdir(parents=True, exist_ok=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()

    def set_imu(self, imu: ImuData) -> None:
        """IMU samples (``imu.t`` seconds on the image clock, before ``time_offset_ns``) and their noise model."""
        self._imu = imu

    def set_ground_truth(self, t, T_w_i, velocity_w=None, gyro_bias=None, accel_bias=None) -> None:
        """Ground truth of the IMU (= body) frame.

        Args:
            t: (N,) seconds, strictly increasing (before ``time_offset_ns``).
            T_w_i: (N, 4, 4) IMU-to-world poses, metres.
            velocity_w, gyro_bias, accel_bias: optional (N, 3) m/s, rad/s, m/s^2; all three
                or none (the 17-column EuRoC table), else the 8-column pose-only table.
        """
        t = check_array("t", t, (None,), finite=True)
        T = check_array("T_w_i", T_w_i, (len(t), 4, 4), finite=True)
        extra = [velocity_w, gyro_bias, accel_bias]
        if any(e is not None for e in extra) and not all(e is not None for e in extra):
            raise InputError("give velocity_w, gyro_bias and accel_bias together, or none of them")
        if extra[0] is not None:
            extra = [check_array(n, e, (len(t), 3), finite=True)
                     for n, e in zip(("velocity_w", "gyro_bias", "accel_bias"), extra)]
        self._gt = (t, T, None if extra[0] is None else np.hstack(extra))

    def add_frame(self, timestamp: float, image) -> str:
        """Write one image at ``timestamp`` seconds; ``image`` (H, W, 3) uint8 RGB or (H, W) grey.

        Returns:
            the file name (``<t_ns>.png``).
        """
        image = np.asarray(image)
        if image.ndim == 3:
            image = check_image("image", image, channels=3)
        else:
            image = check_image("image", image)
        if image.dtype != np.uint8:
            raise InputError(f"image: expected uint8, got {image.dtype}")
        if image.shape[:2] != (self.camera.height, self.camera.width):
            raise InputError(f"image: size {image.shape[1]}x{image.shape[0]} differs from the camera's "
                             f"{self.camera.width}x{self.camera.height}")
        t_ns = int(seconds_to_ns(timestamp)[0]) + self.time_offset_ns
        if self._t_ns and t_ns <= self._t_ns[-1]:
            raise InputError(f"timestamps must increase: {t_ns} ns after {self._t_ns[-1]} ns")
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY if self.grey else cv2.COLOR_RGB2BGR)
        name = f"{t_ns}.png"
        if not cv2.imwrite(str(self.mav0 / "cam0" / "data" / name), image):
            raise InputError(f"{self.mav0 / 'cam0' / 'data' / name}: cannot write image")
        self._t_ns.append(t_ns)
        return name

    def close(self) -> Path:
        """Write the csv and yaml files; returns ``root``."""
        if not self._t_ns:
            raise InputError("no frames were added")
        cam_dir = self.mav0 / "cam0"
        with open(cam_dir / "data.csv", "w", encoding="utf-8") as fh:
            fh.write("#timestamp [ns],filename\n")
            for t in self._t_ns:
                fh.write(f"{t},{t}.png\n")
        c = self.camera
        write_sensor_yaml(cam_dir / "sensor.yaml", "camera", "written by vio_depth.io.asl_writer", self.T_B_C, {
            "rate_hz": self.rate_hz, "resolution": [c.width, c.height], "camera_model": "pinhole",
            "intrinsics": [c.fx, c.fy, c.cx, c.cy], "distortion_model": _ASL_DISTORTION[c.model],
            "distortion_coefficients": list(c.dist) if c.dist else [0.0, 0.0, 0.0, 0.0],
        })
        T_B_I = np.eye(4)
        if self._imu is not None:
            imu = self._imu
            T_B_I = self.T_B_C @ check_transform("imu.T_c_i", imu.T_c_i)
            (self.mav0 / "imu0").mkdir(exist_ok=True)
            rate = 1.0 / float(np.median(np.diff(imu.t))) if len(imu.t) > 1 else 0.0
            write_sensor_yaml(self.mav0 / "imu0" / "sensor.yaml", "imu", "written by vio_depth.io.asl_writer", T_B_I, {
                "rate_hz": round(rate, 6),
                "gyroscope_noise_density": float(imu.gyro_noise), "gyroscope_random_walk": float(imu.gyro_bias_walk),
                "accelerometer_noise_density": float(imu.accel_noise),
                "accelerometer_random_walk": float(imu.accel_bias_walk),
            })
            _write_table(self.mav0 / "imu0" / "data.csv",
                         "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                         "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]",
                         seconds_to_ns(imu.t) + self.time_offset_ns, np.hstack([imu.gyro, imu.accel]))
        if self._gt is not None:
            t, T, extra = self._gt
            gt_dir = self.mav0 / "state_groundtruth_estimate0"
            gt_dir.mkdir(exist_ok=True)
            write_sensor_yaml(gt_dir / "sensor.yaml", "visual-inertial", "ground truth of the IMU (= body) frame",
                              T_B_I, {})
            q = Rotation.from_matrix(T[:, :3, :3]).as_quat()[:, [3, 0, 1, 2]]  # w, x, y, z
            values = np.hstack([T[:, :3, 3], q] + ([] if extra is None else [extra]))
            header = "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"
            if extra is not None:
                header += (", v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], "
                           "b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], "
                           "b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]")
            _write_table(gt_dir / "data.csv", header, seconds_to_ns(t) + self.time_offset_ns, values)
        return self.root


__all__ = ["AslWriter", "seconds_to_ns", "write_sensor_yaml"]
