"""A SIMULATED moving sequence in the EuRoC / TUM-VI ASL layout (no downloaded data needed).

:func:`generate_asl_sample` renders the first frames of a bundled sample's scene and
trajectory (:mod:`vio_depth.simulate.generate`: ``room`` or ``street``), optionally at a
smaller image size, with the sample's noisy 200 Hz IMU (:mod:`vio_depth.simulate.imu`),
and writes them with :class:`vio_depth.io.asl_writer.AslWriter`: grey 8-bit PNGs,
``sensor.yaml`` files, and ground truth of the IMU (= body) frame at the IMU rate,
with the velocity and the true biases (17 columns) or pose only (8 columns).
Timestamps are shifted by ``time_offset_s`` so that they look like a real clock
(nanoseconds since the epoch, as in EuRoC).

``trajectory="loop"`` replaces the sample's trajectory (defined for a few seconds only: 7 s
for the room, 14.5 s for the street) by a periodic closed loop inside the scene
(:func:`vio_depth.simulate.generate.loop_spec`: the room's table walked round every 20 s), so
that sequences of thousands of frames with a consistent IMU can be rendered (e.g. the
1 000-frame memory benchmark, ``benchmarks/bench_stream_memory.py --poses vio``). ``depth_dir``
also saves each frame's exact rendered depth, from which a SIMULATED disparity can be made
without rendering again.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_transform
from vio_core.errors import InputError, lookup
from vio_core.geometry import invert_transform

from ..io.asl_writer import AslWriter
from .generate import camera_poses, loop_spec, sample_spec
from .imu import GRAVITY_W, simulate_imu
from .render import render_view
from .scene_library import build_scene

#: default clock offset of generated ASL samples, seconds (2020-09-13, like a real recording)
ASL_TIME_OFFSET_S = 1_600_000_000


def generate_asl_sample(out_dir, *, sample: str = "room", n_frames: int = 10, scale: float = 1.0,
                        gt_columns: int = 17, gt_start_s: float | None = None,
                        time_offset_s: int = ASL_TIME_OFFSET_S, grey: bool = True, T_i_c=None,
                        trajectory: str = "sample", depth_dir=None) -> Path:
    """Render ``n_frames`` frames of the bundled sample ``sample`` into an ASL folder.

    Args:
        out_dir: output folder (gets ``mav0/``); an existing ``mav0`` in it is replaced.
        sample: "room" or "street" (scene, trajectory, camera mounting, IMU noise, seeds).
        n_frames: frames to render (at the sample's frame rate, from its first frame time).
        scale: image size factor (e.g. 0.25 for a fast test); intrinsics scale with it.
        gt_columns: 17 (pose, velocity, gyro and accelerometer biases) or 8 (pose only).
        gt_start_s: ground truth starts this many seconds after the first IMU sample
            (None: it covers the whole IMU span), so that early frames have no pose.
        time_offset_s: whole seconds added to every timestamp (exactly, in nanoseconds).
        grey: grey PNGs (as EuRoC) or colour.
        T_i_c: (4, 4) camera-to-IMU mounting instead of the sample's (None: the sample's).
            The IMU, ground truth and images follow it; an axis-permutation rotation with
            dyadic translations keeps every transform of the loaders exact (used where two
            loaders must give bit-identical poses: tests/vio_depth/io/test_bag.py).
        trajectory: "sample" (the bundled sample's own motion: a few seconds inside its scene)
            or "loop" (a closed loop repeating every 20 s inside the scene, for any length up to
            an hour; "room" only: :func:`vio_depth.simulate.generate.loop_spec`).
        depth_dir: folder (created) that gets each frame's exact rendered z-depth, float32
            metres (H, W) at ``scale``, as ``<image stem>.npy`` (the PNG's name: its timestamp in
            ns); None: not saved.

    Returns:
        ``out_dir``. The disparity of such a sequence is not stored; the images are
        SIMULATED renderings.
    """
    spec = lookup("trajectory", trajectory, {"sample": sample_spec, "loop": loop_spec})(sample)
    if T_i_c is not None:
        spec = replace(spec, T_i_c=check_transform("T_i_c", T_i_c))
    if n_frames < 1:
        raise InputError(f"n_frames must be positive, got {n_frames}")
    if gt_columns not in (8, 17):
        raise InputError(f"gt_columns must be 8 or 17, got {gt_columns}")
    out = Path(out_dir)
    if (out / "mav0").exists():
        shutil.rmtree(out / "mav0")
    camera = spec.camera if scale == 1.0 else spec.camera.scaled(scale)
    scene = build_scene(spec.scene, spec.scene_seed)
    traj = spec.make_trajectory(spec.seed)
    t_frames = spec.frame_times(n_frames)
    t_imu = spec.imu_times(n_frames)
    T_c_i = invert_transform(spec.T_i_c)
    imu, truth = simulate_imu(traj, t_imu, T_c_i, noise=spec.imu_noise, seed=spec.seed, gravity_w=GRAVITY_W)
    writer = AslWriter(out, camera, spec.T_i_c, grey=grey, rate_hz=spec.frame_rate_hz,
                       time_offset_ns=int(time_offset_s) * 10**9, overwrite=True)
    writer.set_imu(imu)  # body = IMU frame: T_B_C = T_i_c
    keep = np.ones(len(t_imu), bool) if gt_start_s is None else t_imu >= t_imu[0] + gt_start_s
    state = traj.state(t_imu[keep])
    if gt_columns == 17:
        writer.set_ground_truth(t_imu[keep], state.T_w_i(), state.v_w, truth["gyro_bias"][keep],
                                truth["accel_bias"][keep])
    else:
        writer.set_ground_truth(t_imu[keep], state.T_w_i())
    T_w_c = camera_poses(spec, traj, t_frames)
    depth_out = None if depth_dir is None else Path(depth_dir)
    if depth_out is not None:
        depth_out.mkdir(parents=True, exist_ok=True)
    for i, (t, T) in enumerate(zip(t_frames, T_w_c)):
        view = render_view(scene, camera, T, settings=spec.render, noise_seed=[spec.seed, 3, i])
        name = writer.add_frame(float(t), view.image)
        if depth_out is not None:
            np.save(depth_out / f"{Path(name).stem}.npy", view.depth.astype(np.float32))
    return writer.close()


def asl_sample_camera(sample: str = "room", scale: float = 1.0) -> Camera:
    """The camera :func:`generate_asl_sample` writes for ``sample`` at ``scale``."""
    cam = sample_spec(sample).camera
    return cam if scale == 1.0 else cam.scaled(scale)


__all__ = ["ASL_TIME_OFFSET_S", "asl_sample_camera", "generate_asl_sample"]
