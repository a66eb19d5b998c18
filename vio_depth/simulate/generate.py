"""Deterministic generation of the bundled sample sequences (``sample_sequences/``).

Each sample is described by a :class:`SampleSpec` (scene, camera, frame rate, trajectory,
IMU mounting and noise, seeds); :func:`generate_sample` renders it into a native sequence
folder. Everything is seeded, nothing is downloaded, and the output files are
byte-identical from run to run on the same software stack (numpy, scipy, OpenCV,
scikit-image versions), which ``SHA256SUMS`` lets one check.

The disparity of the samples is SIMULATED at load time from the ground-truth depth
(:mod:`vio_depth.disparity.simulation`); no disparity files are stored.
"""

from __future__ import annotations

import hashlib
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array
from vio_core.errors import InputError, lookup
from vio_core.geometry import invert_transform, make_transform

from ..disparity import DisparitySpec, disparity_preset
from ..io.native_writer import NativeSequenceWriter
from .imu import GRAVITY_W, ImuNoise, simulate_imu
from .render import RenderSettings, render_view
from .scene_library import build_scene
from .trajectory import (
    DrivingTrajectory,
    Sinusoids,
    SinusoidTrajectory,
    Trajectory,
    euler_zyx_to_matrix,
    plan_drive,
    smoothstep,
)

#: IMU (x forward, y left, z up) to camera (x right, y down, z forward) axis permutation
R_I_C_BASE = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def camera_mount(translation_i, yaw_deg: float = 0.0, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """``T_i_c: (4, 4)`` camera-to-IMU transform of a forward-looking camera.

    The camera sits at ``translation_i: (3,)`` metres in the IMU frame and looks along the
    IMU x axis, turned by the given ZYX angles about the IMU axes (positive pitch tilts
    it down).
    """
    translation_i = check_array("translation_i", translation_i, (3,), finite=True)
    R = euler_zyx_to_matrix(np.radians([[yaw_deg, pitch_deg, roll_deg]]))[0]
    return make_transform(R @ R_I_C_BASE, translation_i)


@dataclass(frozen=True)
class SampleSpec:
    """Everything that defines one generated sample sequence.

    Attributes:
        name: folder name. description: one paragraph for sequence.json.
        scene: scene name (:func:`vio_depth.simulate.scenes.build_scene`). scene_seed: its seed.
        camera: intrinsics (undistorted).
        frame_rate_hz, n_frames, first_frame_s: frame timing (frame i at first + i / rate).
        imu_rate_hz: IMU sample rate; samples start at t = 0 and run to the last frame + 0.5 s.
        make_trajectory: seed -> IMU trajectory covering [0, last frame + 0.5 s].
        T_i_c: (4, 4) camera-to-IMU mounting.
        imu_noise: noise model. seed: master seed (trajectory, IMU noise, sensor noise).
        disparity_seed: seed of the SIMULATED disparity.
        render: renderer settings. jpeg_quality: image JPEG quality.
    """

    name: str
    description: str
    scene: str
    scene_seed: int
    camera: Camera
    frame_rate_hz: float
    n_frames: int
    make_trajectory: Callable[[int], Trajectory]
    T_i_c: np.ndarray
    seed: int
    disparity_seed: int
    first_frame_s: float = 0.5
    imu_rate_hz: float = 200.0
    imu_noise: ImuNoise = field(default_factory=ImuNoise)
    render: RenderSettings = field(default_factory=RenderSettings)
    jpeg_quality: int = 90

    def frame_times(self, n_frames: int | None = None) -> np.ndarray:
        n = self.n_frames if n_frames is None else n_frames
        return self.first_frame_s + np.arange(n) / self.frame_rate_hz

    def imu_times(self, n_frames: int | None = None) -> np.ndarray:
        end = self.frame_times(n_frames)[-1] + 0.5
        return np.arange(int(round(end * self.imu_rate_hz)) + 1) / self.imu_rate_hz


def street_trajectory(seed: int) -> DrivingTrajectory:
    """Car on the street scene: right lane of street A northwards, right turn at the
    junction into street B eastwards. Speed 4 -> 7 -> 4.4 (turn) -> 8 m/s; IMU 0.93 m
    above the road; covers t in [0, 14.5] s."""
    rng = np.random.default_rng([seed, 1])
    S = smoothstep

    def speed(t):
        return 4.0 + 3.0 * S((t - 0.5) / 3.0) - 2.6 * S((t - 4.5) / 2.0) + 3.6 * S((t - 8.0) / 3.0)

    ramp, length = 4.0, 13.0
    t = np.arange(0.0, 14.5 + 1e-9, 0.05)
    straight = plan_drive(speed, lambda s: 0.0 * s, t, start_heading=np.pi / 2)
    s_turn = float(np.interp(6.0, t, straight[:, 1] - straight[0, 1]))  # arc length where the turn starts
    k = (np.pi / 2) / length  # integral of the curvature = -pi/2 (right turn)

    def curvature(s):
        return -k * (S((s - s_turn) / ramp) - S((s - s_turn - length) / ramp))

    xy = plan_drive(speed, curvature, t, start_heading=np.pi / 2)
    xy = xy + np.array([1.75, 48.25 - xy[-1, 1]])  # right lanes: x = 1.75 on A, y = 48.25 on B
    height = Sinusoids([0.93], [0.0], [[0.004, 0.001]], [[0.9, 2.1]], [rng.uniform(0, 2 * np.pi, 2)])
    pitch_roll = Sinusoids([0.0, 0.0], [0.0, 0.0], [[0.004, 0.002], [0.003, 0.0015]], [[0.7, 1.9], [0.5, 1.3]],
                           rng.uniform(0, 2 * np.pi, (2, 2)))
    return DrivingTrajectory(t, xy, height, pitch_roll)


def room_trajectory(seed: int) -> SinusoidTrajectory:
    """Hand-held walk through the room: starts in the corner near (0.5, 0.45) m looking at
    the opposite corner (depths up to ~7 m), walks diagonally across the room, tilting
    down over the table around t = 3 s (depths down to ~0.5 m) while panning left about
    150 degrees, with slow sway and small hand shake; covers t in [0, 7] s."""
    rng = np.random.default_rng([seed, 2])
    phase = rng.uniform(0, 2 * np.pi, (6, 3))
    start = np.array([0.5, 0.45, 1.4])
    amp = np.array([[0.08, 0.03, 0.003], [0.08, 0.025, 0.003], [0.06, 0.02, 0.002]])
    freq = np.array([[0.13, 0.7, 2.3], [0.11, 0.8, 2.1], [0.17, 0.9, 2.7]])
    position = Sinusoids(offset=start - (amp * np.sin(phase[:3])).sum(1), rate=[0.5, 0.45, -0.02],
                         amp=amp, freq=freq, phase=phase[:3])
    e_amp = np.array([[0.15, 0.04, 0.004], [0.32, 0.04, 0.003], [0.05, 0.02, 0.002]])
    e_freq = np.array([[0.15, 0.6, 2.5], [0.12, 0.5, 2.2], [0.2, 0.7, 2.9]])
    e_phase = phase[3:].copy()
    e_phase[1, 0] = np.pi / 2 - 2 * np.pi * e_freq[1, 0] * 3.0  # largest downward pitch at t = 3 s
    yaw0 = np.arctan2(5.0 - start[1], 6.0 - start[0])  # towards the far corner (6, 5)
    e_offset = np.array([yaw0 - (e_amp[0] * np.sin(e_phase[0])).sum(), 0.12, 0.0])
    euler = Sinusoids(offset=e_offset, rate=[0.5, 0.0, 0.0], amp=e_amp, freq=e_freq, phase=e_phase)
    return SinusoidTrajectory(position, euler, 0.0, 7.0)


#: period of :func:`room_loop_trajectory`, seconds (every frequency in it is a multiple of 1 / period)
ROOM_LOOP_PERIOD_S = 20.0
#: centre (x, y) and semi-axes (along x, along y) of :func:`room_loop_trajectory`'s ellipse, metres
ROOM_LOOP_CENTRE, ROOM_LOOP_AXES = (2.9, 2.45), (1.6, 1.15)


def room_loop_trajectory(seed: int, duration_s: float = 3600.0) -> SinusoidTrajectory:
    """Hand-held walk round and round the room's table, for long runs: the IMU goes
    anticlockwise along an ellipse about (2.9, 2.45) m with semi-axes 1.6 x 1.15 m (x in
    [1.3, 4.5], y in [1.3, 3.6] before the sway: clear of the table, sofa, cabinets and boxes) at
    1.4 m height, about 0.43 m/s, facing the middle of the room (yaw = the position's angle
    + 180 degrees, plus a slow pan) tilted down about 7 degrees, so it sees the table and the
    opposite walls (depths about 1-5.5 m); the room sample's sway (0.7-0.9 Hz, 2-3 cm) and
    hand shake (2.1-2.9 Hz, 2-3 mm).

    Every frequency is a multiple of ``1 / ROOM_LOOP_PERIOD_S`` (20 s) and the yaw turns by
    exactly 2 pi per period, so the pose, velocity, acceleration and body rate repeat exactly
    every 20 s: the path is a closed loop that can be followed for ``duration_s`` seconds (t in
    [0, duration_s]) with an IMU consistent with it throughout."""
    rng = np.random.default_rng([seed, 4])
    w = 1.0 / ROOM_LOOP_PERIOD_S  # Hz
    (cx, cy), (ax, ay) = ROOM_LOOP_CENTRE, ROOM_LOOP_AXES
    phase = rng.uniform(0, 2 * np.pi, (6, 2))
    # x = cx + ax cos(2 pi w t), y = cy + ay sin(2 pi w t): the loop; then sway and shake
    amp = np.array([[ax, 0.03, 0.003], [ay, 0.025, 0.003], [0.0, 0.02, 0.002]])
    freq = w * np.array([[1, 14, 46], [1, 16, 42], [1, 18, 54]])
    pos_phase = np.concatenate([np.array([[np.pi / 2], [0.0], [0.0]]), phase[:3]], axis=1)
    position = Sinusoids(offset=[cx, cy, 1.4], rate=[0.0, 0.0, 0.0], amp=amp, freq=freq, phase=pos_phase)
    # yaw faces the centre (angle + pi) and pans +-0.15 rad at 0.15 Hz; pitch 0.12 rad down
    e_amp = np.array([[0.15, 0.04, 0.004], [0.04, 0.04, 0.003], [0.0, 0.02, 0.002]])
    e_freq = w * np.array([[3, 12, 50], [2, 10, 44], [1, 14, 58]])
    e_phase = np.concatenate([rng.uniform(0, 2 * np.pi, (3, 1)), phase[3:]], axis=1)
    euler = Sinusoids(offset=[np.pi, 0.12, 0.0], rate=[2 * np.pi * w, 0.0, 0.0], amp=e_amp, freq=e_freq,
                      phase=e_phase)
    return SinusoidTrajectory(position, euler, 0.0, duration_s)


_SPECS = {
    "street": SampleSpec(
        name="street",
        description=("SIMULATED outdoor street (rendered, not real): a car drives north on street A at 4-7 m/s, "
                     "slows to 4.4 m/s for a right turn at a T-junction and accelerates to 8 m/s on street B. "
                     "Camera 1.6 m above the road, 10 Hz; IMU 200 Hz. Sky pixels have no depth (0). "
                     "Disparity is SIMULATED from the ground-truth depth at load time."),
        scene="street", scene_seed=11,
        camera=Camera(640, 256, 360.0, 360.0, 319.5, 127.5),
        frame_rate_hz=10.0, n_frames=130,
        make_trajectory=street_trajectory,
        T_i_c=camera_mount([1.05, -0.32, 0.67], yaw_deg=0.5, pitch_deg=1.5, roll_deg=-0.3),
        seed=101, disparity_seed=1001,
    ),
    "room": SampleSpec(
        name="room",
        description=("SIMULATED indoor room (rendered, not real), 6 x 5 x 3 m with furniture and posters, "
                     "hand-held camera walking diagonally across it while panning, 20 Hz, a few cm per frame; "
                     "depths about 0.5-7 m; IMU 200 Hz. "
                     "Disparity is SIMULATED from the ground-truth depth at load time."),
        scene="room", scene_seed=7,
        camera=Camera(512, 384, 420.0, 420.0, 255.5, 191.5),
        frame_rate_hz=20.0, n_frames=120,
        make_trajectory=room_trajectory,
        T_i_c=camera_mount([0.03, -0.05, 0.02], yaw_deg=-1.0, pitch_deg=2.0, roll_deg=1.5),
        seed=202, disparity_seed=2002,
    ),
}


def sample_names() -> list[str]:
    """Names of the bundled samples."""
    return sorted(_SPECS)


def sample_spec(name: str) -> SampleSpec:
    """The :class:`SampleSpec` called ``name``.

    Raises:
        UnknownNameError: unknown name (lists the valid ones).
    """
    return lookup("sample sequence", name, _SPECS)


#: sample name -> (its closed-loop trajectory, description) (:func:`loop_spec`)
_LOOPS = {
    "room": (room_loop_trajectory,
             "SIMULATED indoor room (rendered, not real), 6 x 5 x 3 m with furniture and posters, hand-held camera "
             "walking round and round the table facing the middle of the room (a closed loop every 20 s, "
             "about 2 cm per frame), 20 Hz; depths about 1-5.5 m; IMU 200 Hz (SIMULATED)."),
}


def loop_spec(name: str) -> SampleSpec:
    """The bundled sample ``name`` (scene, camera, frame rate, mounting, IMU noise, seeds) with
    a periodic closed-loop trajectory that stays inside its scene for an hour
    (:func:`room_loop_trajectory`; only "room" has one): for long SIMULATED runs.

    Raises:
        UnknownNameError: no loop for ``name`` (lists the valid ones).
    """
    make, description = lookup("loop trajectory", name, _LOOPS)
    return replace(sample_spec(name), name=f"{name}_loop", make_trajectory=make, description=description)


def camera_poses(spec: SampleSpec, trajectory: Trajectory, t) -> np.ndarray:
    """(K, 4, 4) camera-to-world poses ``T_w_c = T_w_i T_i_c`` at ``t: (K,)`` seconds."""
    return trajectory.T_w_i(t) @ spec.T_i_c


def generate_sample(spec: SampleSpec | str, out_dir, *, n_frames: int | None = None,
                    progress: Callable[[str], None] | None = None) -> Path:
    """Render the sample ``spec`` into the native sequence folder ``out_dir``.

    An existing ``out_dir`` holding a ``sequence.json`` is replaced; any other non-empty
    folder is refused. ``n_frames`` (default: the spec's) shortens the sequence.

    Returns:
        ``out_dir``.
    """
    spec = sample_spec(spec) if isinstance(spec, str) else spec
    out = Path(out_dir)
    if out.exists():
        if (out / "sequence.json").is_file():
            shutil.rmtree(out)
        elif any(out.iterdir()):
            raise InputError(f"{out}: exists and is not a sequence folder; refusing to overwrite it")
    n = spec.n_frames if n_frames is None else int(n_frames)
    if n < 1:
        raise InputError(f"n_frames must be positive, got {n}")
    scene = build_scene(spec.scene, spec.scene_seed)
    traj = spec.make_trajectory(spec.seed)
    t_frames = spec.frame_times(n)
    t_imu = spec.imu_times(n)
    poses = camera_poses(spec, traj, t_frames)
    T_c_i = invert_transform(spec.T_i_c)
    imu, truth = simulate_imu(traj, t_imu, T_c_i, noise=spec.imu_noise, seed=spec.seed, gravity_w=GRAVITY_W)
    metadata = {
        "simulated": True,
        "generator": "python -m vio_depth.simulate",
        "description": spec.description,
        "scene": spec.scene,
        "scene_seed": spec.scene_seed,
        "seed": spec.seed,
        "render": {"supersampling": spec.render.supersampling, "max_aniso": spec.render.max_aniso,
                   "noise_dn": spec.render.noise_dn, "jpeg_quality": spec.jpeg_quality},
    }
    imu_notes = {"seed": spec.seed, "noise": spec.imu_noise.to_json(),
                 "initial_gyro_bias": truth["gyro_bias"][0].tolist(),
                 "initial_accel_bias": truth["accel_bias"][0].tolist()}
    writer = NativeSequenceWriter(out, spec.name, spec.camera, image_ext=".jpg", jpeg_quality=spec.jpeg_quality,
                                  metadata=metadata)
    writer.set_imu(imu, simulation=imu_notes)
    writer.set_disparity(DisparitySpec.simulated(spec.disparity_seed, disparity_preset("default")))
    start = time.perf_counter()
    for i, (t, T_w_c) in enumerate(zip(t_frames, poses)):
        view = render_view(scene, spec.camera, T_w_c, settings=spec.render, noise_seed=[spec.seed, 3, i])
        writer.add_frame(float(t), view.image, T_w_c, depth=view.depth)
        if progress is not None and (i + 1) % 10 == 0:
            progress(f"{spec.name}: {i + 1}/{n} frames ({time.perf_counter() - start:.0f} s)")
    return writer.close()


def write_checksums(root, names) -> Path:
    """Write ``root/SHA256SUMS`` for every file of the sample folders ``names`` (sorted paths)."""
    root = Path(root)
    lines = []
    for name in sorted(names):
        for p in sorted((root / name).rglob("*")):
            if p.is_file():
                digest = hashlib.sha256(p.read_bytes()).hexdigest()
                lines.append(f"{digest}  {p.relative_to(root).as_posix()}\n")
    out = root / "SHA256SUMS"
    out.write_text("".join(lines), encoding="utf-8")
    return out
