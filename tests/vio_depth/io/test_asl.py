"""EuRoC / TUM-VI (ASL layout) loader: a generated moving sample, hand-made malformed
folders, and the real EuRoC V1_01 slice in ../shared/data (skipped when absent)."""

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.errors import SequenceFormatError
from vio_core.geometry import invert_transform
from vio_depth.io import open_sequence
from vio_depth.io.asl import AslSequence
from vio_depth.simulate.asl import ASL_TIME_OFFSET_S, generate_asl_sample
from vio_depth.simulate.generate import sample_spec
from vio_depth.simulate.imu import simulate_imu

REPO = Path(__file__).resolve().parents[3]
EUROC = REPO / ".." / "shared" / "data" / "euroc_v101_static"
N_FRAMES = 6
pytest.importorskip("skimage")  # the generator's textures


@pytest.fixture(scope="module")
def asl_room(tmp_path_factory):
    """A SIMULATED moving ASL sample: 6 frames of the room at 1/4 size, 17-column ground truth."""
    return generate_asl_sample(tmp_path_factory.mktemp("asl") / "room", n_frames=N_FRAMES, scale=0.25)


@pytest.fixture()
def copy_of(asl_room, tmp_path):
    root = tmp_path / "seq"
    shutil.copytree(asl_room, root)
    return root


def _truth(n=N_FRAMES):
    spec = sample_spec("room")
    traj = spec.make_trajectory(spec.seed)
    t = spec.frame_times(n)
    return spec, traj, t, traj.T_w_i(t) @ spec.T_i_c


# --------------------------------------------------------------------------- generated sample
def test_generated_sample_is_auto_detected_with_exact_poses_imu_and_velocity(asl_room):
    seq = open_sequence(asl_room)
    assert isinstance(seq, AslSequence) and len(seq) == N_FRAMES and seq.name == "room"
    spec, traj, t, T_w_c = _truth()
    assert (seq.camera.width, seq.camera.height) == (128, 96) and seq.camera.fx == pytest.approx(105.0)
    for i, f in enumerate(seq):
        assert f.timestamp == pytest.approx(t[i] + ASL_TIME_OFFSET_S, abs=1e-6)
        np.testing.assert_allclose(f.T_w_c, T_w_c[i], atol=1e-8)  # frames fall on ground-truth samples
        np.testing.assert_allclose(f.velocity_w, traj.state(t[i : i + 1]).v_w[0], atol=1e-8)
    image = seq[0].image()
    assert image.shape == (96, 128, 3) and image.dtype == np.uint8
    assert np.array_equal(image[..., 0], image[..., 2])  # grey PNG -> 3 equal channels
    # IMU: the sample's simulated stream, T_c_i from the two T_BS
    imu, truth = simulate_imu(traj, spec.imu_times(N_FRAMES), invert_transform(spec.T_i_c), noise=spec.imu_noise,
                              seed=spec.seed)
    np.testing.assert_allclose(seq.imu.t - ASL_TIME_OFFSET_S, imu.t, atol=1e-6)
    np.testing.assert_allclose(seq.imu.gyro, imu.gyro, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(seq.imu.accel, imu.accel, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(seq.imu.T_c_i, invert_transform(spec.T_i_c), atol=1e-12)
    assert seq.imu.gyro_noise == spec.imu_noise.gyro_noise_density
    assert seq.imu.accel_bias_walk == spec.imu_noise.accel_bias_random_walk
    gt = seq.ground_truth
    np.testing.assert_allclose(gt.accel_bias, truth["accel_bias"], atol=1e-12)
    np.testing.assert_allclose(gt.gyro_bias, truth["gyro_bias"], atol=1e-12)


def test_mav0_folder_itself_opens_too(asl_room):
    seq = open_sequence(asl_room / "mav0")
    assert len(seq) == N_FRAMES and seq.name == "room"


def test_frames_without_ground_truth_get_no_pose_and_pose_only_tables_load(tmp_path):
    root = generate_asl_sample(tmp_path / "late", n_frames=4, scale=0.125, gt_columns=8, gt_start_s=0.6)
    seq = open_sequence(root)
    # frames at 0.5, 0.55, 0.6, 0.65 s; ground truth from 0.6 s on
    assert [f.T_w_c is None for f in seq] == [True, True, False, False]
    assert all(f.velocity_w is None for f in seq) and seq.ground_truth.velocity_w is None
    assert seq.n_posed == 2
    _, _, _, T_w_c = _truth(4)
    np.testing.assert_allclose(seq[3].T_w_c, T_w_c[3], atol=1e-8)


def test_sequence_without_ground_truth_or_imu_loads(copy_of):
    shutil.rmtree(copy_of / "mav0" / "state_groundtruth_estimate0")
    seq = open_sequence(copy_of)
    assert seq.ground_truth is None and all(f.T_w_c is None for f in seq) and seq.imu is not None
    shutil.rmtree(copy_of / "mav0" / "imu0")
    seq = open_sequence(copy_of)
    assert seq.imu is None and len(seq) == N_FRAMES


def test_equidistant_camera_and_16_bit_images(copy_of):
    cam_yaml = copy_of / "mav0" / "cam0" / "sensor.yaml"
    text = cam_yaml.read_text().replace("distortion_model: radial-tangential", "distortion_model: equidistant")
    text = text.replace("distortion_coefficients: [0.0, 0.0, 0.0, 0.0]",
                        "distortion_coefficients: [0.0034823, 0.000715, -0.0020532, 2.029e-04]")
    cam_yaml.write_text(text)
    first = sorted((copy_of / "mav0" / "cam0" / "data").glob("*.png"))[0]
    grey = cv2.imread(str(first), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(first), grey.astype(np.uint16) * 257)
    seq = open_sequence(copy_of)
    assert seq.camera.model == "equidistant" and seq.camera.dist[3] == pytest.approx(2.029e-4)
    np.testing.assert_array_equal(seq[0].image()[..., 1], grey)  # 16 bit -> the same 8-bit values


# --------------------------------------------------------------------------- malformed folders
def _edit_line(path: Path, lineno: int, new: str | None):
    """Replace (or with None delete) 1-based line ``lineno`` of ``path``."""
    lines = path.read_text().splitlines()
    if new is None:
        del lines[lineno - 1]
    else:
        lines[lineno - 1] = new
    path.write_text("\n".join(lines) + "\n")


def _swap_lines(path: Path, a: int, b: int):
    lines = path.read_text().splitlines()
    lines[a - 1], lines[b - 1] = lines[b - 1], lines[a - 1]
    path.write_text("\n".join(lines) + "\n")


def _edit_field(path: Path, lineno: int, field: int, value: str):
    lines = path.read_text().splitlines()
    fields = lines[lineno - 1].split(",")
    fields[field] = value
    lines[lineno - 1] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")


def _replace(path: Path, old: str, new: str):
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


CAM, IMU, GT = "mav0/cam0", "mav0/imu0", "mav0/state_groundtruth_estimate0"
MALFORMED = {
    "missing cam0 csv": (lambda r: (r / CAM / "data.csv").unlink(), f"{CAM}/data.csv: images file not found"),
    "missing imu0 csv": (lambda r: (r / IMU / "data.csv").unlink(), f"{IMU}/data.csv: IMU file not found"),
    "missing cam0 yaml": (lambda r: (r / CAM / "sensor.yaml").unlink(), f"{CAM}/sensor.yaml: sensor.yaml not found"),
    "imu column count": (lambda r: _edit_line(r / IMU / "data.csv", 5, "1600000000500000000,0.1,0.2,0.3,9.8,0.0"),
                         f"{IMU}/data.csv:5: expected 7 comma-separated columns"),
    "gt column count": (lambda r: _edit_line(r / GT / "data.csv", 3, "1600000000005000000,1,2,3,1,0,0,0,5"),
                        f"{GT}/data.csv:3: expected 17 comma-separated columns"),
    "gt non-numeric": (lambda r: _edit_field(r / GT / "data.csv", 4, 2, "zero"),
                       f"{GT}/data.csv:4: non-numeric value"),
    "gt bad quaternion": (lambda r: _edit_line(r / GT / "data.csv", 2, "1600000000000000000,0,0,0,2,0,0,0"
                                                                       + ",0" * 9),
                          f"{GT}/data.csv:2: quaternion norm 2.0000"),
    "cam0 time not increasing": (lambda r: _swap_lines(r / CAM / "data.csv", 3, 4),
                                 f"{CAM}/data.csv:4: timestamps must be strictly increasing"),
    "imu time not increasing": (lambda r: _swap_lines(r / IMU / "data.csv", 10, 11),
                                f"{IMU}/data.csv:11: timestamps must be strictly increasing"),
    "cam0 timestamp not ns": (lambda r: _edit_line(r / CAM / "data.csv", 2, "1.6e18,x.png"),
                              f"{CAM}/data.csv:2: timestamp '1.6e18' is not an integer"),
    "image missing": (lambda r: sorted((r / CAM / "data").glob("*.png"))[2].unlink(),
                      f"{CAM}/data.csv:4: image 'data/"),
    "bad yaml": (lambda r: _replace(r / CAM / "sensor.yaml", "resolution: [", "resolution: [[ ,"),
                 f"{CAM}/sensor.yaml:"),
    "T_BS not a rotation": (lambda r: _replace(r / CAM / "sensor.yaml", "data: [", "data: [3.0, 0.0, 0.0, 0.0, "),
                            f"{CAM}/sensor.yaml:5: T_BS"),
    "T_BS 15 numbers": (lambda r: _replace(r / IMU / "sensor.yaml", "data: [1.0, ", "data: ["),
                        f"{IMU}/sensor.yaml:5: T_BS data must be 16 finite numbers"),
    "noise key missing": (lambda r: _replace(r / IMU / "sensor.yaml", "gyroscope_noise_density", "gyro_noise"),
                          f"{IMU}/sensor.yaml: missing key 'gyroscope_noise_density'"),
    "intrinsics short": (lambda r: _replace(r / CAM / "sensor.yaml", "intrinsics: [", "intrinsics: [1.0]\n#"),
                         f"{CAM}/sensor.yaml:16: intrinsics must be a list of 4"),
    "unknown distortion": (lambda r: _replace(r / CAM / "sensor.yaml", "radial-tangential", "omni"),
                           f"{CAM}/sensor.yaml:17: distortion_model 'omni' is not supported"),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_folder_gives_one_error_naming_file_and_line(copy_of, case):
    corrupt, expected = MALFORMED[case]
    corrupt(copy_of)
    with pytest.raises(SequenceFormatError) as info:
        seq = open_sequence(copy_of)
        seq[2].image()  # lazily read pixels are checked too
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(copy_of / expected.split(":")[0]))
    assert expected in message, message


def test_bad_yaml_names_the_line_of_the_syntax_error(copy_of):
    _replace(copy_of / CAM / "sensor.yaml", "resolution: [", "resolution: [[ ,")
    with pytest.raises(SequenceFormatError, match=r"sensor\.yaml:14: invalid YAML"):
        open_sequence(copy_of)


def test_cli_reports_a_malformed_asl_folder_in_one_line(copy_of, tmp_path, capsys):
    from vio_depth.cli import main

    _edit_line(copy_of / IMU / "data.csv", 7, "1600000000500000000,a,b,c,d,e,f")
    rc = main(["run", str(copy_of), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and len(err.splitlines()) == 1 and "imu0/data.csv:7: non-numeric" in err


# --------------------------------------------------------------------------- real EuRoC slice
@pytest.mark.shared_data
def test_real_euroc_slice():
    if not EUROC.is_dir():
        pytest.skip(f"{EUROC} not present")
    seq = open_sequence(EUROC)
    assert isinstance(seq, AslSequence) and len(seq) == 95
    cam = seq.camera
    assert (cam.width, cam.height, cam.model) == (752, 480, "radtan")
    assert cam.fx == pytest.approx(458.654) and cam.dist[0] == pytest.approx(-0.28340811)
    image = seq[0].image()
    assert image.shape == (480, 752, 3) and image.dtype == np.uint8
    # IMU: the whole 145.6 s stream at 200 Hz, ADIS16448 noise model from sensor.yaml
    assert len(seq.imu.t) == 29120 and seq.imu.gyro_noise == pytest.approx(1.6968e-4)
    assert 1 / np.median(np.diff(seq.imu.t)) == pytest.approx(200.0, rel=1e-3)
    # resting IMU: specific force ~ +g
    assert np.linalg.norm(seq.imu.accel[:200].mean(0)) == pytest.approx(9.81, abs=0.1)
    # ground truth (8 columns) starts at 1403715274.302 s: the first 21 frames have no pose
    posed = [f.T_w_c is not None for f in seq]
    assert posed == [f.timestamp >= 1403715274.30214 for f in seq] and sum(posed) == 74
    assert seq.ground_truth.velocity_w is None and seq[40].velocity_w is None
    # camera pose = body pose from the independent TUM copy of the ground truth, times T_BS
    tum = np.loadtxt(EUROC / "groundtruth_from_openvins" / "V1_01_easy_original.txt")
    f = seq[40]
    j = np.searchsorted(tum[:, 0], f.timestamp)
    a = (f.timestamp - tum[j - 1, 0]) / (tum[j, 0] - tum[j - 1, 0])
    p = (1 - a) * tum[j - 1, 1:4] + a * tum[j, 1:4]
    T_w_b = np.eye(4)
    T_w_b[:3, :3] = Rotation.from_quat(tum[j, 4:8]).as_matrix()
    T_w_b[:3, 3] = p
    T_w_c = T_w_b @ seq.T_B_C
    np.testing.assert_allclose(f.T_w_c[:3, 3], T_w_c[:3, 3], atol=2e-5)  # metres
    assert np.degrees(Rotation.from_matrix(f.T_w_c[:3, :3].T @ T_w_c[:3, :3]).magnitude()) < 0.05
    # camera looks forward from the body: T_c_i is the inverse of cam0's T_BS (imu0's is identity)
    np.testing.assert_allclose(seq.imu.T_c_i, invert_transform(seq.T_B_C), atol=1e-12)
