"""Sample generator: byte-identical reruns, a loadable native sequence, consistent poses/IMU."""

import dataclasses
import hashlib

import numpy as np
import pytest

from vio_core.camera import Camera
from vio_core.errors import InputError, UnknownNameError
from vio_depth.io.native import NativeSequence
from vio_depth.simulate.__main__ import main
from vio_depth.simulate.generate import camera_poses, generate_sample, sample_names, sample_spec
from vio_depth.simulate.imu import ideal_imu


def _small_spec():
    spec = sample_spec("room")
    return dataclasses.replace(spec, camera=Camera(80, 60, 66.0, 66.0, 39.5, 29.5), n_frames=3)


def _files(root):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_generation_is_byte_identical_and_loads(tmp_path):
    spec = _small_spec()
    a = generate_sample(spec, tmp_path / "a")
    b = generate_sample(spec, tmp_path / "b")
    fa, fb = _files(a), _files(b)
    assert sorted(fa) == sorted(fb)
    assert {"sequence.json", "frames.txt", "poses.txt", "imu.txt", "images/000002.jpg", "depth/000002.png"} <= set(fa)
    assert all(fa[k] == fb[k] for k in fa)
    generate_sample(spec, a)  # regenerating in place replaces the folder with identical bytes
    assert _files(a) == fa

    seq = NativeSequence(a)
    assert len(seq) == 3 and seq.disparity.kind == "simulated" and seq.metadata["simulated"] is True
    traj = spec.make_trajectory(spec.seed)
    np.testing.assert_allclose(seq.T_w_c, camera_poses(spec, traj, seq.timestamps), atol=2e-8)
    # T_c_i written with the samples maps the IMU trajectory onto the camera poses
    T_w_i = traj.T_w_i(seq.timestamps)
    np.testing.assert_allclose(seq.T_w_c @ seq.imu.T_c_i, T_w_i, atol=2e-8)
    # IMU samples = exact kinematics + bounded noise/bias (200 Hz, covering the frames)
    assert seq.imu.t[0] <= seq.timestamps[0] and seq.imu.t[-1] >= seq.timestamps[-1]
    assert np.median(np.diff(seq.imu.t)) == pytest.approx(1 / 200)
    gyro, accel = ideal_imu(traj, seq.imu.t)
    assert np.abs(seq.imu.gyro - gyro).max() < 0.02
    assert np.abs(seq.imu.accel - accel).max() < 0.2
    img = seq[1].image()
    assert img.shape == (60, 80, 3) and img.std() > 10
    depth = seq[1].gt_depth()
    assert depth.min() > 0.3 and depth.max() < 8.0  # closed room: every pixel valid


def test_cli_writes_checksums_and_refuses_foreign_folders(tmp_path):
    out = tmp_path / "out"
    assert main(["--out", str(out), "--only", "room", "--frames", "1", "--quiet"]) == 0
    lines = (out / "SHA256SUMS").read_text().splitlines()
    assert lines and all(name.startswith("room/") for _, name in (ln.split("  ") for ln in lines))
    for digest, name in (ln.split("  ") for ln in lines):
        assert hashlib.sha256((out / name).read_bytes()).hexdigest() == digest
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "keep.txt").write_text("mine")
    with pytest.raises(InputError):
        generate_sample(_small_spec(), foreign)
    assert (foreign / "keep.txt").exists()
    assert sample_names() == ["room", "street"]
    with pytest.raises(UnknownNameError):
        sample_spec("forest")
