"""Tests of vio_depth/io/ddad.py on small synthetic scenes written in the DGP layout."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.errors import InputError, SequenceFormatError, UnknownNameError
from vio_core.geometry import invert_transform, make_transform
from vio_depth.io import open_sequence
from vio_depth.io.ddad import DdadSequence, DdadSettings, ddad_split_scenes, find_ddad_scenes, parse_timestamp

W, H, F = 64, 48, 40.0
# camera looking along the vehicle's x axis (vehicle: x forward, y left, z up)
R_V_C = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
T_V_C = make_transform(R_V_C, [1.5, 0.2, 1.4])
T_V_L = make_transform(Rotation.from_euler("z", 20, degrees=True).as_matrix(), [0.0, 0.0, 1.9])
CAL_KEY = "c0e1a6f1c439b282be0066d8dfcad9dd54782030"


def _pose_json(T):
    q = Rotation.from_matrix(T[:3, :3]).as_quat()  # x y z w
    return {"rotation": {"qw": q[3], "qx": q[0], "qy": q[1], "qz": q[2]},
            "translation": {"x": T[0, 3], "y": T[1, 3], "z": T[2, 3]}}


def _T_w_v(k: int, dt: float = 0.0):
    """Vehicle pose at frame k (+ dt frames): 1 m and 1 degree of yaw per frame."""
    s = k + dt
    return make_transform(Rotation.from_euler("z", s, degrees=True).as_matrix(), [1.0 * s, 0.1 * s, 0.0])


def _world_points():
    """A wall 25 m ahead and a box, sampled densely (metres, world frame)."""
    yy, zz = np.meshgrid(np.linspace(-15, 15, 200), np.linspace(0, 8, 60))
    wall = np.stack([np.full(yy.size, 25.0), yy.ravel(), zz.ravel()], 1)
    by, bz = np.meshgrid(np.linspace(-1, 1, 40), np.linspace(0, 2, 40))
    box = np.stack([np.full(by.size, 12.0), by.ravel() + 0.5, bz.ravel()], 1)
    return np.vstack([wall, box])


def _stamp(k: int) -> str:
    return f"2019-07-05T18:11:{21 + k // 10:02d}.{(k % 10) * 100000:06d}Z"


def write_scene(root: Path, n: int = 4, *, camel: bool = False, lidar_dt: float = 0.0, name: str = "000150") -> Path:
    """Write a DGP scene folder with ``n`` samples (camera CAMERA_01, LiDAR LIDAR) and return it.

    The LiDAR of sample k is captured at vehicle pose ``_T_w_v(k, lidar_dt)``.
    """
    scene = root / name
    (scene / "calibration").mkdir(parents=True)
    (scene / "rgb" / "CAMERA_01").mkdir(parents=True)
    (scene / "point_cloud" / "LIDAR").mkdir(parents=True)
    cal = {"names": ["LIDAR", "CAMERA_01"],
           "intrinsics": [{"cx": 0.0, "cy": 0.0, "fx": 0.0, "fy": 0.0, "skew": 0.0},
                          {"cx": 31.5, "cy": 23.5, "fx": F, "fy": F, "skew": 0.0}],
           "extrinsics": [_pose_json(T_V_L), _pose_json(T_V_C)]}
    (scene / "calibration" / f"{CAL_KEY}.json").write_text(json.dumps(cal, indent=2))
    rng = np.random.default_rng(0)
    X_w = _world_points()
    data, samples = [], []
    key = (lambda s: "".join(p if i == 0 else p.title() for i, p in enumerate(s.split("_")))) if camel else str
    for k in range(n):
        ts = f"1562350281{k:02d}0000"
        img = f"rgb/CAMERA_01/{ts}.png"
        cv2.imwrite(str(scene / img), rng.integers(0, 255, (H, W, 3), dtype=np.uint8))
        T_w_l = _T_w_v(k, lidar_dt) @ T_V_L
        X_l = X_w @ invert_transform(T_w_l)[:3, :3].T + invert_transform(T_w_l)[:3, 3]
        pc = f"point_cloud/LIDAR/{ts}.npz"
        np.savez_compressed(scene / pc, data=np.hstack([X_l, np.ones((len(X_l), 1))]).astype(np.float64))
        cam_key, lidar_key = f"cam{k:04d}", f"lidar{k:04d}"
        data.append({"datum": {key("point_cloud"): {"filename": pc, key("point_format"): ["X", "Y", "Z", "INTENSITY"],
                                                     "pose": _pose_json(T_w_l)}},
                     "id": {"index": "0", "log": "TEST", "name": "LIDAR", "timestamp": _stamp(k)}, "key": lidar_key})
        data.append({"datum": {"image": {"channels": 3, "filename": img, "height": H, "width": W,
                                         "pose": _pose_json(_T_w_v(k) @ T_V_C)}},
                     "id": {"index": "0", "log": "TEST", "name": "CAMERA_01", "timestamp": _stamp(k)}, "key": cam_key})
        samples.append({key("calibration_key"): CAL_KEY, key("datum_keys"): [lidar_key, cam_key],
                        "id": {"index": "0", "timestamp": _stamp(k)}})
    (scene / "scene_a8dc5ed1da0923563f85ea129f0e0a83e7fe1867.json").write_text(
        json.dumps({"data": data, "samples": samples, "name": name, "log": "TEST"}, indent=2))
    return scene


def _expected_depth(k: int) -> np.ndarray:
    """Ground truth computed independently: world points into camera k, nearest per pixel."""
    T_c_w = invert_transform(_T_w_v(k) @ T_V_C)
    p = _world_points() @ T_c_w[:3, :3].T + T_c_w[:3, 3]
    p = p[p[:, 2] > 0.1]
    u = np.round(F * p[:, 0] / p[:, 2] + 31.5).astype(int)
    v = np.round(F * p[:, 1] / p[:, 2] + 23.5).astype(int)
    ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    depth = np.full((H, W), np.inf)
    np.minimum.at(depth, (v[ok], u[ok]), p[ok, 2])
    depth[np.isinf(depth)] = 0.0
    return depth.astype(np.float32)


def test_scene_loads_with_poses_intrinsics_timestamps_and_lidar_depth(tmp_path):
    scene = write_scene(tmp_path)
    seq = open_sequence(scene)
    assert seq.format_name == "ddad" and len(seq) == 4 and seq.imu is None and seq.has_gt_depth
    cam = seq.camera
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (W, H, F, F, 31.5, 23.5)
    for k in range(4):
        f = seq.frame(k)
        np.testing.assert_allclose(f.T_w_c, _T_w_v(k) @ T_V_C, atol=1e-9)
        assert f.image().shape == (H, W, 3)
        depth = f.gt_depth()
        exp = _expected_depth(k)
        assert (depth > 0).sum() > 200
        np.testing.assert_array_equal(depth > 0, exp > 0)
        np.testing.assert_allclose(depth, exp, rtol=1e-5)
    stamps = [seq.frame(k).timestamp for k in range(4)]
    np.testing.assert_allclose(np.diff(stamps), 0.1, atol=1e-6)
    assert seq.frame(0).stem == "1562350281000000"


def test_camel_case_json_and_the_scene_json_path_are_accepted(tmp_path):
    scene = write_scene(tmp_path, camel=True)
    scene_json = next(scene.glob("scene_*.json"))
    seq = open_sequence(scene_json)
    assert seq.format_name == "ddad" and len(seq) == 4
    np.testing.assert_allclose(seq.frame(2).gt_depth(), _expected_depth(2), rtol=1e-5)


def test_projection_with_poses_compensates_lidar_timing(tmp_path):
    """LiDAR captured 0.3 frames before the image: world poses place its points right, extrinsics do not."""
    scene = write_scene(tmp_path, lidar_dt=-0.3)
    default = open_sequence(scene, format="ddad")
    assert default.settings.project_with == "extrinsics"
    poses = DdadSequence(scene, DdadSettings(project_with="poses")).frame(2).gt_depth()
    extr = default.frame(2).gt_depth()
    exp = _expected_depth(2)
    np.testing.assert_allclose(poses, exp, rtol=1e-5)
    both = (extr > 0) & (exp > 0)
    assert np.median(np.abs(extr[both] - exp[both]) / exp[both]) > 0.005  # ~0.3 m off at 12-25 m


def test_dataset_root_lists_its_scenes_and_split_file(tmp_path):
    a = write_scene(tmp_path, n=2, name="000150")
    b = write_scene(tmp_path, n=2, name="000151")
    assert find_ddad_scenes(tmp_path) == [a, b]
    with pytest.raises(InputError, match="2 scenes.*000150"):
        open_sequence(tmp_path)
    (tmp_path / "ddad.json").write_text(json.dumps({"metadata": {}, "scene_splits": {
        "0": {"filenames": [f"000150/{next(a.glob('scene_*.json')).name}"]},
        "1": {"filenames": [f"000151/{next(b.glob('scene_*.json')).name}"]}}}))
    val = ddad_split_scenes(tmp_path / "ddad.json", "val")
    assert len(val) == 1 and val[0].parent == b and len(open_sequence(val[0])) == 2
    with pytest.raises(UnknownNameError, match="val"):
        ddad_split_scenes(tmp_path / "ddad.json", "validation")
    with pytest.raises(SequenceFormatError, match="no scenes in split 'test'"):
        ddad_split_scenes(tmp_path / "ddad.json", "test")


def test_json_syntax_error_names_file_and_line(tmp_path):
    scene = write_scene(tmp_path, n=2)
    path = next(scene.glob("scene_*.json"))
    lines = path.read_text().splitlines()
    lines[3] = lines[3] + " oops"
    path.write_text("\n".join(lines))
    with pytest.raises(SequenceFormatError) as err:
        open_sequence(scene)
    assert str(err.value).startswith(f"{path}:4: invalid JSON")


def _edit_scene(scene: Path, fn) -> Path:
    path = next(scene.glob("scene_*.json"))
    obj = json.loads(path.read_text())
    fn(obj)
    path.write_text(json.dumps(obj))
    return path


def test_structural_errors_name_the_file_and_the_entry(tmp_path):
    scene = write_scene(tmp_path / "a", n=3)
    path = _edit_scene(scene, lambda o: o["samples"][1]["datum_keys"].append("nope"))
    with pytest.raises(SequenceFormatError, match=rf"^{path}: samples\[1\]: datum key 'nope' is not in 'data'"):
        open_sequence(scene)
    scene = write_scene(tmp_path / "b", n=3)
    path = _edit_scene(scene, lambda o: o["samples"][2].pop("calibration_key"))
    with pytest.raises(SequenceFormatError, match=r"samples\[2\]: missing 'calibration_key'"):
        open_sequence(scene)
    scene = write_scene(tmp_path / "c", n=3)
    path = _edit_scene(scene, lambda o: o["data"][1]["datum"]["image"]["pose"]["rotation"].update(qw=3.0))
    with pytest.raises(SequenceFormatError, match=rf"^{path}: datum 'cam0000' pose: rotation quaternion norm"):
        open_sequence(scene)
    scene = write_scene(tmp_path / "d", n=3)
    (scene / "calibration" / f"{CAL_KEY}.json").unlink()
    with pytest.raises(SequenceFormatError, match=rf"calibration/{CAL_KEY}.json: calibration file not found"):
        open_sequence(scene)
    scene = write_scene(tmp_path / "e", n=3)
    with pytest.raises(InputError, match="no sample has a datum named 'CAMERA_05'; datums: CAMERA_01, LIDAR"):
        DdadSequence(scene, DdadSettings(camera="CAMERA_05"))


def test_bad_calibration_and_point_cloud_files_are_named(tmp_path):
    scene = write_scene(tmp_path / "a", n=2)
    cal = scene / "calibration" / f"{CAL_KEY}.json"
    obj = json.loads(cal.read_text())
    obj["intrinsics"].pop()
    cal.write_text(json.dumps(obj))
    with pytest.raises(SequenceFormatError, match=rf"^{cal}: calibration: 2 names, 1 intrinsics"):
        open_sequence(scene)
    scene = write_scene(tmp_path / "b", n=2)
    npz = next((scene / "point_cloud" / "LIDAR").glob("*.npz"))
    npz.write_bytes(b"not a zip file")
    seq = open_sequence(scene)
    first = seq.frame(0) if seq.frame(0).stem == npz.stem else seq.frame(1)
    with pytest.raises(SequenceFormatError, match=rf"^{npz}: cannot read point cloud"):
        first.gt_depth()
    scene = write_scene(tmp_path / "c", n=2)
    npz = next((scene / "point_cloud" / "LIDAR").glob("*.npz"))
    np.savez_compressed(npz, points=np.zeros((3, 4)))
    seq = open_sequence(scene)
    idx = [seq.frame(i).stem for i in range(2)].index(npz.stem)
    with pytest.raises(SequenceFormatError, match="expected key 'data'"):
        seq.frame(idx).gt_depth()


def test_timestamps_parse_as_rfc3339():
    assert parse_timestamp("1970-01-01T00:00:01.5Z", "x", "t") == 1.5
    assert parse_timestamp("1970-01-01T01:00:00+01:00", "x", "t") == 0.0
    assert parse_timestamp("2463-05-15T00:38:58.203752Z", "x", "t") > 1e10  # DGP test data's far future
    with pytest.raises(SequenceFormatError, match="not RFC 3339"):
        parse_timestamp("15623502810000000", "scene.json", "datum 'x'")
