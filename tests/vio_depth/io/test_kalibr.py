"""Kalibr camchain.yaml / imu.yaml: reading real-style files, exact round trips, errors with
file and line, and applying a calibration to any sequence."""

import numpy as np
import pytest

from vio_core.camera import Camera
from vio_core.errors import InputError, SequenceFormatError
from vio_depth.frame import ImuData
from vio_depth.io import open_sequence
from vio_depth.io.kalibr import (
    Calibration,
    CalibratedSequence,
    apply_calibration,
    read_calibration,
    read_camchain,
    read_imu_yaml,
    write_camchain,
    write_imu_yaml,
)

#: EuRoC's cam0 as Kalibr writes it (camchain-imucam of the EuRoC calibration sequences)
EUROC_CAMCHAIN = """\
cam0:
  T_cam_imu:
  - [0.0148655429818, 0.999557249008, -0.0257744366974, 0.0652229095355]
  - [-0.999880929698, 0.0149672133247, 0.00375618835797, -0.0207063854198]
  - [0.00414029679422, 0.0257155299480, 0.999660727178, -0.00805460800345]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
  timeshift_cam_imu: 0.0015
cam1:
  T_cam_imu:
  - [1.0, 0.0, 0.0, 0.0]
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  distortion_coeffs: [0.0, 0.0, 0.0, 0.0]
  distortion_model: equidistant
  intrinsics: [457.587, 456.134, 379.999, 255.238]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
"""

IMU_YAML = """\
#Accelerometers
accelerometer_noise_density: 2.0e-3
accelerometer_random_walk: 3.0e-3
#Gyroscopes
gyroscope_noise_density: 1.6968e-04
gyroscope_random_walk: 1.9393e-05
rostopic: /imu0
update_rate: 200.0
"""


def test_reads_euroc_style_camchain_and_flat_imu_yaml(tmp_path):
    (tmp_path / "camchain.yaml").write_text(EUROC_CAMCHAIN)
    (tmp_path / "imu.yaml").write_text(IMU_YAML)
    cam = read_camchain(tmp_path / "camchain.yaml")
    assert cam.name == "cam0" and cam.rostopic == "/cam0/image_raw" and cam.timeshift_cam_imu == 0.0015
    assert cam.camera == Camera(752, 480, 458.654, 457.296, 367.215, 248.375,
                                (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05), "radtan")
    assert cam.T_c_i[0, 3] == 0.0652229095355 and cam.T_c_i[1, 0] == -0.999880929698
    other = read_camchain(tmp_path / "camchain.yaml", topic="/cam1/image_raw")
    assert other.name == "cam1" and other.camera.model == "equidistant"
    imu = read_imu_yaml(tmp_path / "imu.yaml")
    assert (imu.accel_noise, imu.accel_bias_walk, imu.gyro_noise, imu.gyro_bias_walk) == (2e-3, 3e-3, 1.6968e-4,
                                                                                          1.9393e-5)
    assert imu.rostopic == "/imu0" and imu.update_rate == 200.0


@pytest.mark.parametrize("camera", [
    Camera(640, 480, 500.25, 501.5, 319.75, 240.125, (-0.2, 0.05, 1e-4, -2e-5), "radtan"),
    Camera(640, 480, 500.25, 501.5, 319.75, 240.125, (-0.2, 0.05, 1e-4, -2e-5, 0.001), "radtan"),
    Camera(752, 480, 190.97, 190.97, 254.93, 256.89, (0.0034, 0.00071, -0.0020, 0.00020), "equidistant"),
    Camera(320, 240, 250.0, 250.0, 159.5, 119.5),
])
def test_camchain_and_imu_yaml_round_trip_exactly(tmp_path, camera):
    rng = np.random.default_rng(3)
    from scipy.spatial.transform import Rotation
    T_c_i = np.eye(4)
    T_c_i[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    T_c_i[:3, 3] = rng.normal(size=3) * 0.1
    imu = ImuData(np.arange(3) / 200.0, np.zeros((3, 3)), np.tile([0, 0, 9.81], (3, 1)), T_c_i,
                  gyro_noise=1.7e-4, accel_noise=2.0e-3, gyro_bias_walk=1.9393e-05, accel_bias_walk=3e-3)
    write_camchain(tmp_path / "c.yaml", camera, T_c_i, timeshift_cam_imu=-0.00125, rostopic="/cam/image")
    write_imu_yaml(tmp_path / "i.yaml", imu, rostopic="/imu", update_rate=200.0)
    calib = read_calibration(tmp_path / "c.yaml", tmp_path / "i.yaml")
    assert calib.camera.camera == camera
    assert np.array_equal(calib.camera.T_c_i, T_c_i) and calib.camera.timeshift_cam_imu == -0.00125
    assert (calib.imu.gyro_noise, calib.imu.accel_noise, calib.imu.gyro_bias_walk, calib.imu.accel_bias_walk) == \
        (imu.gyro_noise, imu.accel_noise, imu.gyro_bias_walk, imu.accel_bias_walk)


def test_an_asl_sequence_calibration_round_trips_into_the_same_camera_and_imu_settings(tmp_path):
    pytest.importorskip("skimage")
    from vio_depth.simulate.asl import generate_asl_sample

    seq = open_sequence(generate_asl_sample(tmp_path / "asl", n_frames=3, scale=0.25))
    write_camchain(tmp_path / "camchain.yaml", seq.camera, seq.imu.T_c_i)
    write_imu_yaml(tmp_path / "imu.yaml", seq.imu)
    again = apply_calibration(seq, read_calibration(tmp_path / "camchain.yaml", tmp_path / "imu.yaml"))
    assert isinstance(again, CalibratedSequence) and again.camera == seq.camera and again[1].camera == seq.camera
    for name in ("t", "gyro", "accel", "T_c_i"):
        assert np.array_equal(getattr(again.imu, name), getattr(seq.imu, name)), name
    for name in ("gyro_noise", "accel_noise", "gyro_bias_walk", "accel_bias_walk", "gravity_w"):
        assert getattr(again.imu, name) == getattr(seq.imu, name), name
    assert np.array_equal(again[2].T_w_c, seq[2].T_w_c) and np.array_equal(again[2].image(), seq[2].image())


def test_a_calibration_replaces_camera_extrinsic_noise_and_shifts_the_imu_clock(tmp_path):
    pytest.importorskip("skimage")
    from vio_depth.simulate.asl import generate_asl_sample

    seq = open_sequence(generate_asl_sample(tmp_path / "asl", n_frames=3, scale=0.25))
    cam = Camera(seq.camera.width, seq.camera.height, 100.0, 101.0, 63.0, 47.0, (-0.1, 0.01, 0.0, 0.0))
    T = np.eye(4)
    T[:3, 3] = [0.1, 0.2, 0.3]
    write_camchain(tmp_path / "c.yaml", cam, T, timeshift_cam_imu=0.002)
    (tmp_path / "i.yaml").write_text("imu0:\n  gyroscope_noise_density: 0.001\n  gyroscope_random_walk: 0.0001\n"
                                     "  accelerometer_noise_density: 0.01\n  accelerometer_random_walk: 0.001\n")
    out = apply_calibration(seq, read_calibration(tmp_path / "c.yaml", tmp_path / "i.yaml"))
    assert out.camera == cam and out[0].camera == cam and np.array_equal(out.imu.T_c_i, T)
    np.testing.assert_array_equal(out.imu.t, seq.imu.t - 0.002)  # t_cam = t_imu - timeshift_cam_imu
    assert (out.imu.gyro_noise, out.imu.gyro_bias_walk, out.imu.accel_noise, out.imu.accel_bias_walk) == \
        (0.001, 0.0001, 0.01, 0.001)
    assert apply_calibration(seq, Calibration()) is seq
    write_camchain(tmp_path / "small.yaml", Camera(64, 48, 50.0, 50.0, 31.5, 23.5))
    with pytest.raises(InputError, match="64x48 but the images"):
        apply_calibration(seq, read_calibration(tmp_path / "small.yaml"))


@pytest.mark.parametrize("edit, message, line", [
    (lambda t: t.replace("camera_model: pinhole", "camera_model: omni", 1), "camera_model: 'omni' is not supported", 8),
    (lambda t: t.replace("distortion_model: radtan", "distortion_model: fov", 1), "'fov' is not supported", 10),
    (lambda t: t.replace("[458.654, 457.296, 367.215, 248.375]", "[458.654, 457.296]"), "intrinsics", 11),
    (lambda t: t.replace("[0.0148655429818, 0.999557249008", "[2.0148655429818, 0.999557249008"), "T_cam_imu", 2),
    (lambda t: t.replace("  resolution: [752, 480]\n", "", 1), "missing key 'resolution'", 1),
    (lambda t: t.replace("timeshift_cam_imu: 0.0015", "timeshift_cam_imu: soon"), "timeshift_cam_imu", 14),
    (lambda t: t.replace("cam0:", "camera:").replace("cam1:", "other:"), "not a Kalibr camchain", None),
    (lambda t: t.replace("  camera_model: pinhole\n", "  camera_model: [pinhole\n", 1), "invalid YAML", None),
])
def test_malformed_camchain_names_file_and_line(tmp_path, edit, message, line):
    path = tmp_path / "camchain.yaml"
    path.write_text(edit(EUROC_CAMCHAIN))
    with pytest.raises(SequenceFormatError, match=message) as info:
        read_camchain(path)
    assert str(path) in str(info.value)
    if line is not None:
        assert info.value.line == line, str(info.value)


def test_imu_yaml_needs_positive_densities_and_the_right_topic_is_required(tmp_path):
    (tmp_path / "i.yaml").write_text(IMU_YAML.replace("noise_density: 1.6968e-04", "noise_density: 0"))
    with pytest.raises(SequenceFormatError, match="gyroscope_noise_density: must be a positive number") as info:
        read_imu_yaml(tmp_path / "i.yaml")
    assert info.value.line == 5
    (tmp_path / "c.yaml").write_text(EUROC_CAMCHAIN)
    with pytest.raises(SequenceFormatError, match=r"no camera calibrated on /cam9/image: cam0 \(/cam0/image_raw\)"):
        read_camchain(tmp_path / "c.yaml", topic="/cam9/image")
    with pytest.raises(SequenceFormatError, match="calibration file not found"):
        read_camchain(tmp_path / "missing.yaml")


def test_cli_applies_calib_to_a_folder_input(tmp_path, capsys):
    pytest.importorskip("skimage")
    from vio_depth.cli import main
    from vio_depth.simulate.asl import generate_asl_sample

    root = generate_asl_sample(tmp_path / "asl", n_frames=3, scale=0.25)
    write_camchain(tmp_path / "small.yaml", Camera(64, 48, 50.0, 50.0, 31.5, 23.5))
    rc = main(["run", str(root), "--out", str(tmp_path / "o"), "--calib", str(tmp_path / "small.yaml")])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and len(err.splitlines()) == 1 and "--calib: cam0 is 64x48 but the images" in err
    assert not (tmp_path / "o").exists()
