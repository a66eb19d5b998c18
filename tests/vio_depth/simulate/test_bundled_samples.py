"""The bundled SIMULATED samples (sample_sequences/) load and keep their promises."""

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from vio_core.geometry import invert_transform, transform_points
from vio_depth.disparity import DisparityKind, DisparitySettings, create_disparity_source
from vio_depth.io import open_sequence
from vio_depth.simulate.generate import camera_poses, sample_spec
from vio_depth.simulate.imu import ideal_imu

SAMPLES = Path(__file__).resolve().parents[3] / "sample_sequences"

pytestmark = pytest.mark.skipif(not (SAMPLES / "street" / "sequence.json").is_file(),
                                reason="sample_sequences/ not present")

# name: (frames, min depth bound, max depth bound, sky expected)
PROMISES = {"street": (100, 2.5, 50.0, True), "room": (100, 0.7, 6.0, False)}


@pytest.fixture(scope="module", params=sorted(PROMISES))
def sample(request):
    return request.param, open_sequence(SAMPLES / request.param)


def test_sample_loads_with_imu_depth_and_simulated_disparity(sample):
    name, seq = sample
    n_min, near, far, sky = PROMISES[name]
    assert seq.format_name == "native" and len(seq) >= n_min
    assert seq.has_gt_depth and seq.disparity.kind == DisparityKind.SIMULATED and seq.metadata["simulated"] is True
    assert 1.0 / np.median(np.diff(seq.imu.t)) == pytest.approx(200.0)
    assert seq.imu.t[0] <= seq.timestamps[0] and seq.imu.t[-1] >= seq.timestamps[-1]
    assert not np.allclose(seq.imu.T_c_i, np.eye(4))
    f = seq[len(seq) // 2]
    source = create_disparity_source(DisparitySettings(), seq)
    img, depth, disp = f.image(), f.gt_depth(), source(f)
    assert img.shape == (seq.camera.height, seq.camera.width, 3) and img.dtype == np.uint8
    assert disp.shape == depth.shape and source.kind == DisparityKind.SIMULATED
    # simulated disparity is (nearly) affine in 1/depth: strong correlation on valid pixels
    valid = depth > 0
    assert np.corrcoef(disp[valid], 1.0 / depth[valid])[0, 1] > 0.98


def test_depth_range_as_promised(sample):
    name, seq = sample
    _, near, far, sky = PROMISES[name]
    lo, hi, sky_seen = np.inf, 0.0, False
    for f in seq:
        d = f.gt_depth()
        valid = d > 0
        lo, hi = min(lo, d[valid].min()), max(hi, d[valid].max())
        sky_seen |= bool((~valid).any())
    assert lo <= near and hi >= far and sky_seen == sky
    if name == "room":
        assert lo >= 0.4 and hi <= 8.0


def test_depth_and_poses_are_consistent_across_frames(sample):
    """Back-project GT depth of one frame, move it with the poses, compare with another
    frame's depth (1/depth interpolated bilinearly: exact on planes up to 1/256 m quantisation)."""
    _, seq = sample
    cam = seq.camera
    errors, z_all = [], []
    for i, j in ((0, 1), (len(seq) // 2, len(seq) // 2 + 3)):
        a, b = seq[i], seq[j]
        da, db = a.gt_depth().astype(np.float64), b.gt_depth().astype(np.float64)
        v, u = np.nonzero(da > 0)
        pts = transform_points(invert_transform(b.T_w_c) @ a.T_w_c,
                               cam.backproject(np.stack([u, v], 1).astype(float), da[v, u]))
        uv, z = cam.project(pts)
        ok = (z > 0) & cam.in_image(uv, margin=1.5)
        uv, z = uv[ok], z[ok]
        x0, y0 = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        fx, fy = uv[:, 0] - x0, uv[:, 1] - y0
        c = np.stack([db[y0, x0], db[y0, x0 + 1], db[y0 + 1, x0], db[y0 + 1, x0 + 1]], 1)
        valid = (c > 0).all(1)
        q = 1.0 / np.where(c > 0, c, np.inf)
        qi = q[:, 0] * (1 - fx) * (1 - fy) + q[:, 1] * fx * (1 - fy) + q[:, 2] * (1 - fx) * fy + q[:, 3] * fx * fy
        errors.append(np.abs(1.0 / qi[valid] - z[valid]))
        z_all.append(z[valid])
    err, z = np.concatenate(errors), np.concatenate(z_all)
    assert np.median(err) < 0.003  # quantisation is 1/256 m = 3.9 mm per map
    assert np.mean(err < 0.01 + 0.002 * z) > 0.85  # the rest: occlusions and depth edges


def test_files_match_the_generator_trajectory_and_imu(sample):
    name, seq = sample
    spec = sample_spec(name)
    traj = spec.make_trajectory(spec.seed)
    np.testing.assert_allclose(seq.T_w_c, camera_poses(spec, traj, seq.timestamps), atol=2e-8)
    gyro, accel = ideal_imu(traj, seq.imu.t)
    # residual = bias + white noise (densities in sequence.json)
    assert np.abs(np.median(seq.imu.gyro - gyro, axis=0)).max() < 0.01
    assert np.abs(np.median(seq.imu.accel - accel, axis=0)).max() < 0.1
    white = np.diff(seq.imu.gyro - gyro, axis=0).std(0) / np.sqrt(2)
    np.testing.assert_allclose(white, seq.imu.gyro_noise * np.sqrt(200), rtol=0.15)


def test_sift_finds_hundreds_of_features(sample):
    _, seq = sample
    sift = cv2.SIFT_create()
    counts = [len(sift.detect(cv2.cvtColor(seq[i].image(), cv2.COLOR_RGB2GRAY)))
              for i in (0, len(seq) // 2, len(seq) - 1)]
    assert min(counts) >= 300


def test_checksums_match_the_bundle():
    lines = (SAMPLES / "SHA256SUMS").read_text().splitlines()
    names = set()
    for line in lines:
        digest, name = line.split("  ")
        names.add(name)
        assert hashlib.sha256((SAMPLES / name).read_bytes()).hexdigest() == digest, name
    on_disk = {p.relative_to(SAMPLES).as_posix() for d in PROMISES for p in (SAMPLES / d).rglob("*") if p.is_file()}
    assert names == on_disk
