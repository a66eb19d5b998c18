"""Native sequence format: writer/loader round trip, laziness and malformed-input errors."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.camera import Camera
from vio_core.errors import InputError, SequenceFormatError
from vio_depth.disparity import DisparityKind, DisparitySettings, DisparitySpec, create_disparity_source
from vio_depth.disparity.simulation import disparity_preset, simulate_disparity
from vio_depth.frame import ImuData
from vio_depth.io import depth_png, images, open_sequence
from vio_depth.io.native import NativeSequence
from vio_depth.io.native_writer import NativeSequenceWriter, write_native_sequence

CAM = Camera(32, 24, 30.0, 31.0, 15.5, 11.5)
N = 5


def _data(seed=0):
    rng = np.random.default_rng(seed)
    t = 10.0 + np.arange(N) * 0.1
    images = [rng.integers(0, 256, (CAM.height, CAM.width, 3), dtype=np.uint8) for _ in range(N)]
    poses = []
    for _ in range(N):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.5, 3)).as_matrix()
        T[:3, 3] = rng.normal(0, 3, 3)
        poses.append(T)
    depths = [rng.uniform(0.5, 80.0, (CAM.height, CAM.width)) for _ in range(N)]
    depths[0][:3] = 0.0  # some invalid pixels
    t_imu = 9.9 + np.arange(130) / 200.0
    T_c_i = np.eye(4)
    T_c_i[:3, :3] = Rotation.from_euler("xyz", [90, -90, 3], degrees=True).as_matrix()
    T_c_i[:3, 3] = [0.1, -0.2, 0.05]
    imu = ImuData(t_imu, rng.normal(0, 0.3, (130, 3)), rng.normal(0, 3, (130, 3)), T_c_i,
                  gyro_noise=1e-3, accel_noise=2e-2, gyro_bias_walk=3e-5, accel_bias_walk=4e-3,
                  gravity_w=(0.0, 0.0, -9.80665))
    return t, images, poses, depths, imu


def _write(root, disparity="simulated", seed=0):
    t, images, poses, depths, imu = _data(seed)
    kwargs = {}
    if disparity == "simulated":
        kwargs["disparity"] = DisparitySpec.simulated(5, disparity_preset("default"))
    elif disparity == "files":
        rng = np.random.default_rng(1)
        kwargs["disparities"] = [rng.uniform(0, 10, (CAM.height, CAM.width)).astype(np.float32) for _ in range(N)]
    write_native_sequence(root, "tiny", CAM, t, images, poses, depths=depths, imu=imu, image_ext=".png", **kwargs)
    return t, images, poses, depths, imu, kwargs


def test_round_trip_exact_or_within_stated_tolerance(tmp_path):
    t, images, poses, depths, imu, _ = _write(tmp_path / "seq", disparity="files")
    seq = open_sequence(tmp_path / "seq")
    assert isinstance(seq, NativeSequence) and seq.format_name == "native"
    assert seq.name == "tiny" and seq.camera == CAM and len(seq) == N
    assert seq.has_gt_depth and seq.disparity.kind == DisparityKind.FILES
    for i, f in enumerate(seq):
        assert f.index == i and f.stem == f"{i:06d}"
        assert f.timestamp == pytest.approx(t[i], abs=1e-9)
        np.testing.assert_allclose(f.T_w_c, poses[i], atol=1e-8)  # 9 decimals in poses.txt
        img = f.image()
        assert img.dtype == np.uint8 and img.shape == (CAM.height, CAM.width, 3)
        assert np.array_equal(img, images[i])  # PNG: lossless, RGB order kept
        d = f.gt_depth()
        valid = depths[i] > 0
        assert np.all(d[~valid] == 0)
        assert np.max(np.abs(d[valid] - depths[i][valid])) <= 0.5 / 256 + 1e-4
    np.testing.assert_allclose(seq.imu.t, imu.t, atol=1e-9)
    np.testing.assert_allclose(seq.imu.gyro, imu.gyro, atol=1e-9)
    np.testing.assert_allclose(seq.imu.accel, imu.accel, atol=1e-9)
    assert np.array_equal(seq.imu.T_c_i, imu.T_c_i)  # JSON floats round-trip exactly
    assert (seq.imu.gyro_noise, seq.imu.accel_noise, seq.imu.gyro_bias_walk, seq.imu.accel_bias_walk) == \
        (1e-3, 2e-2, 3e-5, 4e-3)
    assert seq.imu.gravity_w == (0.0, 0.0, -9.80665)
    rng = np.random.default_rng(1)
    disparity = create_disparity_source(DisparitySettings(), seq)
    assert disparity.kind == DisparityKind.FILES
    for i in range(N):
        expected = rng.uniform(0, 10, (CAM.height, CAM.width)).astype(np.float32)
        assert np.array_equal(disparity(seq[i]), expected)


def test_simulated_disparity_is_flagged_and_computed_from_gt_depth(tmp_path):
    _write(tmp_path / "seq", disparity="simulated")
    seq = NativeSequence(tmp_path / "seq")
    assert seq.disparity.kind == DisparityKind.SIMULATED
    disparity = create_disparity_source(DisparitySettings(), seq)
    assert disparity.kind == DisparityKind.SIMULATED  # outputs label it SIMULATED
    f = seq[3]
    expected = simulate_disparity(f.gt_depth(), 5, 3, disparity_preset("default")).disparity
    assert np.array_equal(disparity(f), expected)
    assert not np.array_equal(disparity(seq[2]), expected[:, :])


def test_no_pixels_are_read_until_requested(tmp_path, monkeypatch):
    _write(tmp_path / "seq", disparity="simulated")
    calls = []
    real_read = images.read_image_bytes

    def counting_read(path):
        calls.append(Path(path).name)
        return real_read(path)

    monkeypatch.setattr(images, "read_image_bytes", counting_read)
    monkeypatch.setattr(depth_png, "read_image_bytes", counting_read)
    seq = open_sequence(tmp_path / "seq")
    frames = list(seq)
    assert [f.timestamp for f in frames] and all(f.T_w_c is not None for f in frames)
    assert calls == []  # constructing and iterating read no pixels
    frames[2].image()
    assert calls == ["000002.png"]
    frames[4].gt_depth()
    create_disparity_source(DisparitySettings(), seq)(frames[1])  # simulated: reads that frame's depth only
    assert calls == ["000002.png", "000004.png", "000001.png"]


def test_grey_images_are_expanded_to_rgb(tmp_path):
    _write(tmp_path / "seq", disparity=None)
    grey = np.arange(CAM.width * CAM.height, dtype=np.uint8).reshape(CAM.height, CAM.width)
    cv2.imwrite(str(tmp_path / "seq" / "images" / "000001.png"), grey)
    img = NativeSequence(tmp_path / "seq")[1].image()
    assert img.shape == (CAM.height, CAM.width, 3)
    assert np.array_equal(img[:, :, 0], grey) and np.array_equal(img[:, :, 2], grey)


def _replace_line(path, lineno, text):
    lines = path.read_text().splitlines()
    lines[lineno - 1] = text
    path.write_text("\n".join(lines) + "\n")


def _edit_json(path, fn):
    data = json.loads(path.read_text())
    fn(data)
    path.write_text(json.dumps(data))


# (name, edit(root), file that must be named, expected line or None, message fragment)
MALFORMED = [
    ("frames_columns", lambda r: _replace_line(r / "frames.txt", 3, "10.1 images/000001.png extra"),
     "frames.txt", 3, "columns"),
    ("frames_non_numeric", lambda r: _replace_line(r / "frames.txt", 4, "ten images/000002.png"),
     "frames.txt", 4, "non-numeric"),
    ("frames_not_increasing", lambda r: _replace_line(r / "frames.txt", 4, "10.05 images/000002.png"),
     "frames.txt", 4, "increasing"),
    ("missing_image", lambda r: (r / "images" / "000002.png").unlink(), "frames.txt", 4, "not found"),
    ("poses_columns", lambda r: _replace_line(r / "poses.txt", 2, "10.0 1 2 3 0 0 0"), "poses.txt", 2, "columns"),
    ("poses_non_numeric", lambda r: _replace_line(r / "poses.txt", 3, "10.1 1 2 x 0 0 0 1"),
     "poses.txt", 3, "non-numeric"),
    ("poses_quaternion", lambda r: _replace_line(r / "poses.txt", 4, "10.2 1 2 3 0 0 0.5 1"),
     "poses.txt", 4, "quaternion"),
    ("poses_not_increasing", lambda r: _replace_line(r / "poses.txt", 5, "10.1 1 2 3 0 0 0 1"),
     "poses.txt", 5, "increasing"),
    ("frame_without_pose", lambda r: _replace_line(r / "poses.txt", 4, "10.205 1 2 3 0 0 0 1"),
     "frames.txt", 4, "no pose"),
    ("imu_columns", lambda r: _replace_line(r / "imu.txt", 7, "9.93 1 2 3 4 5"), "imu.txt", 7, "columns"),
    ("imu_not_increasing", lambda r: _replace_line(r / "imu.txt", 9, "9.9 0 0 0 0 0 9.8"),
     "imu.txt", 9, "increasing"),
    ("imu_rate", lambda r: (r / "imu.txt").write_text("9.0 0 0 0 0 0 9.8\n9.1 0 0 0 0 0 9.8\n9.2 0 0 0 0 0 9.8\n"),
     "imu.txt", None, "rate"),
    ("bad_json", lambda r: (r / "sequence.json").write_text('{\n  "format": "vio-depth-sequence",\n  "version": 1,\n'
                                                           '  "name": oops\n}\n'), "sequence.json", 4, "JSON"),
    ("missing_key", lambda r: _edit_json(r / "sequence.json", lambda d: d.pop("camera")), "sequence.json", None,
     "camera"),
    ("missing_camera_key", lambda r: _edit_json(r / "sequence.json", lambda d: d["camera"].pop("fx")),
     "sequence.json", None, "fx"),
    ("unknown_version", lambda r: _edit_json(r / "sequence.json", lambda d: d.update(version=2)),
     "sequence.json", None, "version"),
    ("unknown_key", lambda r: _edit_json(r / "sequence.json", lambda d: d.update(dispartiy={})),
     "sequence.json", None, "dispartiy"),
    ("bad_T_c_i", lambda r: _edit_json(r / "sequence.json", lambda d: d["imu"].update(T_c_i=np.diag([1, 2, 1, 1.]).tolist())),
     "sequence.json", None, "rotation"),
    ("bad_disparity_param", lambda r: _edit_json(r / "sequence.json", lambda d: d["disparity"]["model"].update(blur=1)),
     "sequence.json", None, "blur"),
    ("simulated_without_depth", lambda r: _edit_json(r / "sequence.json", lambda d: d.pop("depth")),
     "sequence.json", None, "depth"),
]


@pytest.mark.parametrize("name, edit, filename, line, fragment", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_input_names_the_file_and_line(tmp_path, name, edit, filename, line, fragment):
    root = tmp_path / "seq"
    _write(root, disparity="simulated")
    NativeSequence(root)  # valid before the edit
    edit(root)
    with pytest.raises(SequenceFormatError) as err:
        NativeSequence(root)
    assert Path(err.value.path).name == filename
    assert err.value.line == line
    assert fragment in str(err.value)


@pytest.mark.parametrize("what", ["image", "depth", "disparity"])
def test_pixel_size_mismatch_is_reported_when_loaded(tmp_path, what):
    root = tmp_path / "seq"
    _write(root, disparity="files")
    if what == "image":
        path = root / "images" / "000001.png"
        cv2.imwrite(str(path), np.zeros((CAM.height + 1, CAM.width, 3), np.uint8))
    elif what == "depth":
        path = root / "depth" / "000001.png"
        cv2.imwrite(str(path), np.ones((CAM.height, CAM.width - 2), np.uint16))
    else:
        path = root / "disparity" / "000001.npy"
        np.save(path, np.zeros((3, 3), np.float32))
    seq = NativeSequence(root)  # opening still works: pixels are not read
    f = seq[1]
    if what == "disparity":  # read by the disparity stage, which names the file
        with pytest.raises(InputError, match=str(path)):
            create_disparity_source(DisparitySettings(), seq)(f)
    else:
        with pytest.raises(SequenceFormatError) as err:
            getattr(f, {"image": "image", "depth": "gt_depth"}[what])()
        assert err.value.path == str(path)
    seq[0].image()  # other frames are unaffected


def test_writer_rejects_bad_frames(tmp_path):
    w = NativeSequenceWriter(tmp_path / "w", "w", CAM)
    img = np.zeros((CAM.height, CAM.width, 3), np.uint8)
    w.add_frame(1.0, img, np.eye(4))
    with pytest.raises(InputError):
        w.add_frame(1.0, img, np.eye(4))  # not increasing
    with pytest.raises(InputError):
        w.add_frame(2.0, img[:-1], np.eye(4))  # wrong size
    with pytest.raises(InputError):
        w.add_frame(2.0, img, np.eye(4), depth=np.ones((CAM.height, CAM.width)))  # depth for some frames only
    w.close()
    with pytest.raises(InputError):
        NativeSequenceWriter(tmp_path / "w", "w", CAM)  # refuses to overwrite without overwrite=True
    assert len(NativeSequence(tmp_path / "w")) == 1


def test_disparity_source_json_round_trip_and_validation():
    src = DisparitySpec.simulated(3, disparity_preset("hard"))
    assert src.to_json()["model"]["distortion"] == disparity_preset("hard").distortion
    assert DisparitySpec.files("d").to_json() == {"kind": "files", "folder": "d"}
    with pytest.raises(InputError):
        DisparitySpec.simulated(-1)


def test_equidistant_camera_round_trips(tmp_path):
    """A fisheye camera keeps its model through write and read; radtan files carry no model key."""
    cam = Camera(32, 24, 20.0, 20.0, 15.5, 11.5, (0.01, -0.002, 0.0005, -0.0001), model="equidistant")
    img = np.zeros((24, 32, 3), np.uint8)
    write_native_sequence(tmp_path / "fish", "fish", cam, [0.0, 0.1], [img, img], [np.eye(4), np.eye(4)])
    assert NativeSequence(tmp_path / "fish").camera == cam
    plain = Camera(32, 24, 20.0, 20.0, 15.5, 11.5)
    write_native_sequence(tmp_path / "plain", "plain", plain, [0.0], [img], [np.eye(4)])
    assert '"model"' not in (tmp_path / "plain" / "sequence.json").read_text()
    assert NativeSequence(tmp_path / "plain").camera == plain
