"""7-Scenes loader: synthetic folders in a temp dir, and the real slice when present."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.errors import InputError, SequenceFormatError
from vio_core.geometry import invert_transform, relative_transform
from vio_depth.evaluation.metrics import depth_reprojection_errors
from vio_depth.io import open_sequence
from vio_depth.io.rasterize import register_depth
from vio_depth.io.sevenscenes import (
    SEVENSCENES_FPS,
    SevenScenesSequence,
    SevenScenesSettings,
)
from vio_depth.pipeline import create_pose_source

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "7scenes_redkitchen"
IDENTITY = tuple(map(tuple, np.eye(4)))


def _pose(i):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.01 * i, -0.02 * i, 0.005 * i]).as_matrix()
    T[:3, 3] = [0.03 * i, 0.01 * i, -0.02 * i]
    return T


def write_7scenes(root, n=4, depth_mm=2000, with_intrinsics=True):
    root.mkdir(parents=True)
    for i in range(n):
        stem = f"frame-{i:06d}"
        img = np.zeros((480, 640, 3), np.uint8)
        img[..., 0] = 30 + i  # red channel in RGB order
        cv2.imwrite(str(root / f"{stem}.color.png"), img[..., ::-1])
        d = np.full((480, 640), depth_mm + 100 * i, np.uint16)
        d[0, :10] = 65535
        d[1, :10] = 0
        cv2.imwrite(str(root / f"{stem}.depth.png"), d)
        np.savetxt(root / f"{stem}.pose.txt", _pose(i))
    if with_intrinsics:
        np.savetxt(root / "camera-intrinsics.txt", np.array([[585.0, 0, 320], [0, 585, 240], [0, 0, 1]]))
    return root


def test_open_and_read_raw(tmp_path):
    root = write_7scenes(tmp_path / "kitchen")
    seq = open_sequence(root)
    assert isinstance(seq, SevenScenesSequence) and seq.format_name == "7scenes"
    assert len(seq) == 4 and seq.has_gt_depth and seq.imu is None
    raw = SevenScenesSequence(root, SevenScenesSettings(T_colour_depth=IDENTITY, register_depth=False))
    f = raw[2]
    assert f.stem == "frame-000002"
    assert f.timestamp == pytest.approx(2 / SEVENSCENES_FPS)
    assert f.image()[5, 5, 0] == 32
    d = f.gt_depth()
    assert d.dtype == np.float32 and d[5, 5] == pytest.approx(2.2)
    assert (d[0, :10] == 0).all() and (d[1, :10] == 0).all()  # 65535 and 0 are invalid
    np.testing.assert_allclose(f.T_w_c, _pose(2), atol=1e-9)


def test_colour_camera_pose_and_registered_depth(tmp_path):
    root = write_7scenes(tmp_path / "kitchen")
    seq = SevenScenesSequence(root)
    assert seq.camera.fx == 525.0 and seq.depth_camera.fx == 585.0
    X = seq.T_colour_depth
    np.testing.assert_allclose(seq[1].T_w_c, _pose(1) @ invert_transform(X), atol=1e-9)
    # a fronto-parallel wall at 2.0 m in the depth camera, seen from the colour camera
    d = seq[0].gt_depth()
    valid = d > 0
    # the colour camera (525 px) sees beyond the depth camera (585 px): the depth covers
    # (525 / 585)^2 of the colour image, without holes inside
    assert valid.mean() == pytest.approx((525 / 585) ** 2, abs=0.01)
    rows, cols = np.nonzero(valid)
    assert valid[rows.min():rows.max() + 1, cols.min():cols.max() + 1].mean() > 0.98  # slightly rotated
    # depth of each registered pixel = z of the wall point in the colour frame
    v, u = np.nonzero(valid)
    pts = seq.camera.backproject(np.stack([u, v], 1).astype(float), d[v, u].astype(float))
    in_depth = pts @ invert_transform(X)[:3, :3].T + invert_transform(X)[:3, 3]
    np.testing.assert_allclose(in_depth[:, 2], 2.0, atol=2e-3)  # back on the wall (pixel rounding)


def test_register_depth_identity_is_lossless():
    cam = Camera(40, 30, 35.0, 35.0, 19.5, 14.5)
    rng = np.random.default_rng(0)
    depth = rng.uniform(1, 3, (30, 40)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.2] = 0
    out = register_depth(depth, cam, cam, np.eye(4))
    np.testing.assert_allclose(out, depth, rtol=1e-6)


def test_imu_pose_source_is_refused(tmp_path):
    seq = open_sequence(write_7scenes(tmp_path / "kitchen"))
    with pytest.raises(InputError, match="sequence has no IMU"):
        create_pose_source("imu", seq)


def test_malformed_files_name_the_file(tmp_path):
    root = write_7scenes(tmp_path / "a")
    (root / "frame-000001.pose.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0\n")
    with pytest.raises(SequenceFormatError, match=r"frame-000001.pose.txt:4: expected 4 columns \(4x4 matrix row\), got 3"):
        open_sequence(root)
    root = write_7scenes(tmp_path / "b")
    (root / "frame-000003.pose.txt").unlink()
    with pytest.raises(SequenceFormatError, match=r"frame-000003.pose.txt"):
        open_sequence(root, format="7scenes")
    root = write_7scenes(tmp_path / "c")
    (root / "camera-intrinsics.txt").write_text("585 0 320\n0 585 240\n")
    with pytest.raises(SequenceFormatError, match=r"camera-intrinsics.txt: expected 3 lines of 3 numbers"):
        open_sequence(root)
    root = write_7scenes(tmp_path / "d")
    (root / "frame-000002.depth.png").write_bytes(b"not a png")
    seq = open_sequence(root)
    with pytest.raises(SequenceFormatError, match="frame-000002.depth.png"):
        seq[2].gt_depth()
    with pytest.raises(InputError, match="not a 7-Scenes folder"):
        SevenScenesSequence(tmp_path)


def test_missing_intrinsics_use_published_depth_camera(tmp_path):
    seq = SevenScenesSequence(write_7scenes(tmp_path / "k", with_intrinsics=False))
    assert seq.depth_camera.fx == 585.0 and seq.depth_camera.cx == 320.0


def _reprojection_error(fa, fb):
    """Median relative error of frame a's depth warped into frame b against b's depth."""
    return np.median(depth_reprojection_errors(fa.gt_depth(), fb.gt_depth(), fa.camera,
                                               relative_transform(fb.T_w_c, fa.T_w_c)))


@pytest.mark.shared_data
def test_real_redkitchen_poses_and_registered_depth_agree():
    if not DATA.is_dir():
        pytest.skip(f"{DATA} not present")
    seq = open_sequence(DATA)
    assert isinstance(seq, SevenScenesSequence) and len(seq) == 300
    errors = [_reprojection_error(seq[a], seq[a + 15]) for a in (0, 100, 200, 280)]
    # measured 0.3-1.1 % (the depth of frame a, warped into frame a+15 with the poses)
    assert max(errors) < 0.02, errors
