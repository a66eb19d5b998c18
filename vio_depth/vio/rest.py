"""Rest detection of the odometry: a zero-velocity test in the style of OpenVINS.

OpenVINS (``UpdaterZeroVelocity``) tests the IMU samples since the last state against the
hypothesis "the body does not move" with a chi-square test, and the image disparity since
the previous frame. Here both must pass (OpenVINS accepts either), and a third image test
bounds the motion since the rest began, because neither of the first two can see a slow
creep: an IMU measures the same at rest and in uniform motion, and a camera creeping at
1-10 cm/s moves its keypoints by less than their noise from one frame to the next
(:class:`~vio_depth.poses.RestSettings` says what each test does and its threshold).

Before, a frame rested when the IMU had been still for 1 s and its keypoints moved less than
1 px since the previous frame and 3 px since the newest keyframe: in the synthetic creep
tests (tests/vio_depth/vio/test_rest.py) a camera creeping at 1, 3 and 10 cm/s was held
still 3 to 9 cm from the truth with a constant 5 mm sigma.

The third test removes the gyroscope's rotation, which is only as good as the gyroscope's
bias; a sideways motion is almost the flow of a rotation, so it counts only beyond the
rotation's uncertainty, measured on the gyroscope's own scatter at rest (a motion along the
view counts whatever the rotation). On the real EuRoC V1_01 still slice, whose platform
vibrates (rotors running), the static start's gyroscope bias is off by 1-2 mrad/s and a fixed
threshold ended the rest after 1.7 s (the odometry then withheld its poses, ``converging``);
now the slice is held still to its end. A camera creeping sideways slower than about that
rotation uncertainty times the depth cannot be told from a gyroscope bias by these tests.
As in OpenVINS (``zupt_max_velocity``), no frame rests while the odometry's newest keyframe
moves faster than ``RestSettings.max_speed_m_s``.

A resting frame keeps the position of the anchor (the last frame before the rest, posed by
the odometry), its orientation follows the gyroscope since the anchor, and its covariance
(relative to the newest keyframe) is the anchor's plus a random walk in the time since it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2 as chi2_distribution

from matchers import Features, Matcher
from vio_core.camera import Camera
from vio_core.checks import check_array
from vio_core.geometry import invert_transform

from ..frame import ImuData
from ..poses import preintegrate
from .settings import RestSettings
from .history import PoseHistory
from .imu_factors import ImuFactors, KeyframeState
from .matching import rotation_free_displacements


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def zero_velocity_chi2(imu: ImuData, R_w_i, accel_bias, gyro_bias, settings: RestSettings) -> tuple[float, int]:
    """Chi-square of ``imu``'s samples under the zero-velocity hypothesis, and its dimension.

    The samples are averaged over consecutive blocks of ``settings.imu_block_s`` seconds (a
    resting platform vibrates: zero-mean accelerations faster than a block average out,
    while a change of velocity does not). Residuals per block ``k`` (IMU frame):
    ``mean gyro_k - gyro_bias`` and ``mean accel_k - accel_bias + R_w_i^T gravity_w`` (at
    rest the accelerometer measures minus gravity). Their covariance: the white noise
    ``imu_noise_multiplier * density^2 / duration_k`` per block, plus the uncertainty of the
    estimates shared by all blocks (roll/pitch ``tilt_sigma_rad``, the two biases), through
    the Woodbury identity.

    Args:
        imu: the samples tested (each covers the interval to the next; the last, the one before it).
        R_w_i: (3, 3) IMU-to-world rotation at rest.
        accel_bias: (3,) m/s^2. gyro_bias: (3,) rad/s.
        settings: :class:`~vio_depth.poses.RestSettings`.

    Returns:
        ``(chi2, dof)``; ``(inf, 0)`` with fewer than two samples.
    """
    R_w_i = check_array("R_w_i", R_w_i, (3, 3), finite=True)
    ba = check_array("accel_bias", accel_bias, (3,), finite=True)
    bg = check_array("gyro_bias", gyro_bias, (3,), finite=True)
    if len(imu.t) < 2:
        return float("inf"), 0
    dt = np.diff(imu.t)
    dt = np.r_[dt, dt[-1]]
    block = np.floor((imu.t - imu.t[0]) / settings.imu_block_s).astype(np.int64)
    starts = np.r_[0, np.nonzero(np.diff(block))[0] + 1]
    duration = np.add.reduceat(dt, starts)
    gyro = np.add.reduceat(imu.gyro * dt[:, None], starts) / duration[:, None]
    accel = np.add.reduceat(imu.accel * dt[:, None], starts) / duration[:, None]
    n = len(starts)
    g_i = R_w_i.T @ np.asarray(imu.gravity_w, float)
    r = np.column_stack([gyro - bg, accel - ba + g_i]).reshape(-1)  # (6n,)
    m = settings.imu_noise_multiplier
    d = np.column_stack([np.repeat((m * imu.gyro_noise ** 2 / duration)[:, None], 3, 1),
                         np.repeat((m * imu.accel_noise ** 2 / duration)[:, None], 3, 1)]).reshape(-1)
    # shared errors: gyro bias (rows 0-2 of every block), accel bias and tilt (rows 3-5)
    H1 = np.zeros((6, 9))
    H1[0:3, 0:3] = np.eye(3)
    H1[3:6, 3:6] = np.eye(3)
    H1[3:6, 6:9] = _skew(g_i)  # R = R0 Exp(theta): R^T g = R0^T g + [R0^T g]x theta
    H = np.tile(H1, (n, 1))
    P_inv = np.diag(1.0 / np.r_[[settings.gyro_bias_sigma ** 2] * 3, [settings.accel_bias_sigma ** 2] * 3,
                                [settings.tilt_sigma_rad ** 2] * 3])
    w = r / d
    Hw = H.T @ w
    M = P_inv + H.T @ (H / d[:, None])
    chi2 = float(r @ w - Hw @ np.linalg.solve(M, Hw))
    return chi2, 6 * n


def gyro_rotation_sigma(imu: ImuData, dt: float, settings: RestSettings) -> float:
    """1-sigma (rad, per axis) of the error of the rotation the gyroscope integrates over ``dt`` seconds.

    Two parts, both from the scatter the gyroscope shows at rest, measured on ``imu``'s samples
    (means over blocks of ``settings.imu_block_s``: a vibrating platform's gyroscope scatters far
    more than its datasheet says, and never less is assumed): the bias, an average over about
    ``settings.gyro_bias_window_s`` of such samples, is off by ``density / sqrt(window)`` and its
    error grows linearly with ``dt``; the white noise integrates to ``density * sqrt(dt)``.

    Args:
        imu: samples of the rest (the scatter is measured on them; at least 3 blocks, else the
            datasheet density). dt: seconds. settings: :class:`~vio_depth.vio.RestSettings`.
    """
    density = float(imu.gyro_noise)  # rad/sqrt(s)
    if len(imu.t) >= 2:
        block = np.floor((imu.t - imu.t[0]) / settings.imu_block_s).astype(np.int64)
        starts = np.r_[0, np.nonzero(np.diff(block))[0] + 1]
        if len(starts) >= 3:
            counts = np.diff(np.r_[starts, len(imu.t)])
            means = np.add.reduceat(imu.gyro, starts) / counts[:, None]
            scatter = float(np.sqrt(np.mean(np.var(means, axis=0, ddof=1))))  # rad/s, over one block
            density = max(density, scatter * np.sqrt(settings.imu_block_s))
    dt = max(float(dt), 0.0)
    return density * float(np.sqrt(dt ** 2 / settings.gyro_bias_window_s + dt))


@dataclass(frozen=True)
class AnchorMotion:
    """How far the camera moved since a reference frame, over the scene's depth (:func:`anchor_motion`).

    Attributes:
        translation: (3,) ``t / Z`` in the reference camera (dimensionless).
        covariance: (3, 3) of ``translation``: keypoint noise and the uncertainty of the
            rotation removed.
        residual_px: median keypoint distance left by the fit, pixels.
    """

    translation: np.ndarray
    covariance: np.ndarray
    residual_px: float

    @property
    def distance(self) -> float:
        """``|t| / Z``."""
        return float(np.linalg.norm(self.translation))

    def sigmas_beyond(self, radius: float) -> float:
        """Mahalanobis distance (in sigmas) from ``translation`` to the nearest motion of at most
        ``radius``: 0 inside the ball; a motion along the view, sure whatever the rotation,
        counts fully, a sideways one only as far as the rotation removed is sure."""
        tau, C = self.translation, self.covariance
        if np.linalg.norm(tau) <= radius:
            return 0.0
        w, V = np.linalg.eigh(C)
        w = np.maximum(w, 1e-30)
        a = V.T @ tau  # nearest point of the ball: tau0 = (I + lam C)^-1 tau, |tau0| = radius
        lo, hi = 0.0, 1.0
        while np.linalg.norm(a / (1.0 + hi * w)) > radius:
            hi *= 4.0
        for _ in range(60):
            lam = 0.5 * (lo + hi)
            lo, hi = (lam, hi) if np.linalg.norm(a / (1.0 + lam * w)) > radius else (lo, lam)
        d = a - a / (1.0 + hi * w)
        return float(np.sqrt(np.sum(d * d / w)))


def anchor_motion(kp_cur, kp_ref, camera: Camera, R_ref_cur, rotation_sigma: float = 0.0) -> AnchorMotion | None:
    """How far the camera moved since a reference frame, over the scene's depth, and how sure that is.

    Once the rotation ``R_ref_cur`` is removed, a small translation ``t`` (metres, reference
    camera) moves a point at depth ``Z`` by ``(1 / Z) [[-fx, 0, x], [0, -fy, y]] t`` pixels
    (``x, y``: its pixel offset from the principal point). With one common inverse depth the
    flow of all matches is linear in ``tau = t / Z`` (3 unknowns), solved by least squares,
    once more without the matches beyond 3 times the median residual (mismatches).

    A rotation error ``w`` (rad, per axis ``rotation_sigma``) moves the point by
    ``[[-u v, 1 + u^2, -v], [-(1 + v^2), u v, u]] w`` times ``fx`` / ``fy`` (``u = x / fx``,
    ``v = y / fy``): nearly the flow of a sideways translation of ``w`` times the depth, while a
    motion along the view expands the flow, which no rotation does. ``sigma`` propagates both
    the keypoint noise (from the fit's residuals) and ``rotation_sigma`` to ``|tau|``: a
    sideways motion is only as sure as the rotation removed, a motion along the view is sure
    whatever the rotation.

    Args:
        kp_cur: (N, 2) raw pixels now. kp_ref: (N, 2) raw pixels of the same points in the
            reference image. camera: both images' camera.
        R_ref_cur: (3, 3) rotation of the current camera into the reference one (gyroscope).
        rotation_sigma: rad, 1-sigma per axis of the error of ``R_ref_cur``.

    Returns:
        The motion, or None with fewer than 8 rays in front.
    """
    kp_cur = check_array("kp_cur", kp_cur, (None, 2))
    kp_ref = check_array("kp_ref", kp_ref, (len(kp_cur), 2))
    R = check_array("R_ref_cur", R_ref_cur, (3, 3), finite=True)
    ic = camera.undistort_points(np.asarray(kp_cur, float))
    ir = camera.undistort_points(np.asarray(kp_ref, float))
    rays = np.column_stack([(ic[:, 0] - camera.cx) / camera.fx, (ic[:, 1] - camera.cy) / camera.fy, np.ones(len(ic))])
    r = rays @ R.T
    front = r[:, 2] > 1e-6
    if front.sum() < 8:
        return None
    u, v = r[front, 0] / r[front, 2], r[front, 1] / r[front, 2]
    x, y = camera.fx * u, camera.fy * v  # current keypoints in the reference image, from the centre
    flow = np.column_stack([x + camera.cx, y + camera.cy]) - ir[front]
    n = len(x)
    A = np.zeros((2 * n, 3))
    A[0::2, 0], A[0::2, 2] = -camera.fx, x
    A[1::2, 1], A[1::2, 2] = -camera.fy, y
    b = flow.reshape(-1)
    keep = np.ones(n, bool)
    for _ in range(2):
        rows = np.repeat(keep, 2)
        tau = np.linalg.lstsq(A[rows], b[rows], rcond=None)[0]
        res = np.linalg.norm((A @ tau - b).reshape(n, 2), axis=1)
        new_keep = res <= 3.0 * max(float(np.median(res[keep])), 1e-9)
        if new_keep.sum() < 8:
            break
        keep = new_keep
    rows = np.repeat(keep, 2)
    Ak = A[rows]
    J = np.zeros((2 * n, 3))
    J[0::2] = camera.fx * np.column_stack([-u * v, 1.0 + u * u, -v])
    J[1::2] = camera.fy * np.column_stack([-(1.0 + v * v), u * v, u])
    N = Ak.T @ Ak
    LJ = np.linalg.solve(N, Ak.T @ J[rows])  # how tau follows a rotation error
    residual = float(np.median(res[keep]))
    pixel_var = (residual / np.sqrt(2.0 * np.log(2.0))) ** 2  # per axis: the median of a 2-D normal's norm
    C = pixel_var * np.linalg.inv(N) + rotation_sigma ** 2 * LJ @ LJ.T
    return AnchorMotion(tau, 0.5 * (C + C.T), residual)


@dataclass(frozen=True)
class RestAnchor:
    """The frame whose pose a rest holds.

    Attributes:
        frame_id, t: the frame (seconds). features: its keypoints.
        T_w_c: (4, 4) camera-to-world, metres, when the rest began.
        covariance: (6, 6) of its pose relative to ``keyframe`` (right perturbation).
        keyframe: the newest keyframe of the window during the rest.
    """

    frame_id: int
    t: float
    features: Features
    T_w_c: np.ndarray
    covariance: np.ndarray
    keyframe: int


@dataclass(frozen=True)
class RestTest:
    """The zero-velocity test of one frame.

    Attributes:
        rest: all tests passed. reason: the first that failed, or the figures of a rest.
        T_w_c: (4, 4) the resting frame's pose, or None.
        covariance: (6, 6) relative to the anchor's keyframe, or None.
        chi2 / chi2_threshold: the IMU test. disparity_px: median keypoint motion since the
        previous frame. anchor_motion: distance moved since the anchor over the scene's depth
        (:func:`anchor_motion`); anchor_motion_sigmas: how many sigma beyond
        ``RestSettings.max_anchor_motion`` (:meth:`AnchorMotion.sigmas_beyond`).
    """

    rest: bool
    reason: str
    T_w_c: np.ndarray | None = None
    covariance: np.ndarray | None = None
    chi2: float = float("nan")
    chi2_threshold: float = float("nan")
    disparity_px: float = float("nan")
    anchor_motion: float = float("nan")
    anchor_motion_sigmas: float = float("nan")


class RestDetector:
    """Decides, frame by frame, whether a tracked camera rests (module docstring).

    Args:
        factors: the odometry's IMU factors (samples, preintegration parameters, ``T_c_i``).
        matcher: matches the frames' features.
        settings: :class:`~vio_depth.poses.RestSettings`.
        max_sample_gap_s: largest gap between IMU samples integrated, seconds.
    """

    def __init__(self, factors: ImuFactors, matcher: Matcher, settings: RestSettings, max_sample_gap_s: float):
        self.factors = factors
        self.matcher = matcher
        self.settings = settings
        self.max_sample_gap_s = float(max_sample_gap_s)
        self.anchor: RestAnchor | None = None
        # (id, t, features) of the previous frame, and whether the odometry posed it
        self._previous: tuple[int, float, Features] | None = None
        self._previous_posed = False
        self._rested = False  # the last test passed

    def observe(self, frame_id: int, t: float, features: Features, posed: bool) -> None:
        """Remember the frame just processed (``posed``: it has a pose in the history). A frame
        that did not pass :meth:`test` ends the rest."""
        self._previous = (int(frame_id), float(t), features)
        self._previous_posed = bool(posed)
        if not self._rested:
            self.anchor = None
        self._rested = False

    def reset(self) -> None:
        """Forget the rest (the window was dropped)."""
        self.anchor = None

    def _rotation(self, state: KeyframeState, t0: float, t1: float) -> np.ndarray | None:
        """(3, 3) IMU rotation from ``t0`` to ``t1`` by the gyroscope (``state``'s biases), or None."""
        pim, _ = preintegrate(self.factors.imu, t0, t1, self.factors.params, state.accel_bias, state.gyro_bias,
                              self.max_sample_gap_s)
        return None if pim is None else pim.deltaRij().matrix()

    def _matches(self, features: Features, other: Features, R_i: np.ndarray):
        """``(kp_now (K, 2), kp_other (K, 2), R_other_now (3, 3) camera rotation)`` of the matches
        of ``features`` with ``other`` (``R_i``: IMU rotation from ``other``'s time to now), or
        None with too few."""
        m = self.matcher.match(features, other)
        if len(m) < self.settings.min_features:
            return None
        R_c_i = self.factors.T_c_i[:3, :3]
        return features.keypoints[m.idx_a], other.keypoints[m.idx_b], R_c_i @ R_i @ R_c_i.T

    def test(self, t: float, camera: Camera, features: Features, keyframe: int, state: KeyframeState,
             history: PoseHistory) -> RestTest:
        """Whether the frame at ``t`` rests; ``keyframe``: the window's newest keyframe, ``state``:
        its state, ``history``: the odometry's poses (the anchor's pose)."""
        s = self.settings
        prev = self._previous
        if prev is None or not self._previous_posed:
            return RestTest(False, "rest continues a posed frame only")
        speed = float(np.linalg.norm(state.velocity_w))
        if not speed <= s.max_speed_m_s:
            return RestTest(False, f"the odometry estimates {speed:.2f} m/s at the newest keyframe")
        # IMU: the samples since the previous frame (at least min_imu_s)
        imu = self.factors.imu.window(min(prev[1], t - s.min_imu_s), t)
        R_kf = self._rotation(state, state.t, t)
        if R_kf is None:
            return RestTest(False, "the IMU does not cover the frame")
        chi2, dof = zero_velocity_chi2(imu, state.T_w_i[:3, :3] @ R_kf, state.accel_bias, state.gyro_bias, s)
        threshold = float(chi2_distribution.ppf(s.chi2_probability, dof)) if dof else 0.0
        if not chi2 <= threshold:
            return RestTest(False, f"IMU moving (chi2 {chi2:.0f} > {threshold:.0f}, {dof} dof)", chi2=chi2,
                            chi2_threshold=threshold)
        R_prev = self._rotation(state, prev[1], t)
        m_prev = None if R_prev is None else self._matches(features, prev[2], R_prev)
        d_prev = None if m_prev is None else rotation_free_displacements(m_prev[0], m_prev[1], camera, camera,
                                                                         m_prev[2])
        if d_prev is None or len(d_prev) < s.min_features:
            return RestTest(False, "too few keypoints matched with the previous frame", chi2=chi2,
                            chi2_threshold=threshold)
        disparity = float(np.median(d_prev))
        if not disparity <= s.max_disparity_px:
            return RestTest(False, f"keypoints moved {disparity:.2f} px since the previous frame", chi2=chi2,
                            chi2_threshold=threshold, disparity_px=disparity)
        anchor = self.anchor
        if anchor is None:
            anchor = self._new_anchor(keyframe, history)
            if anchor is None:
                return RestTest(False, "the previous frame has no pose relative to the newest keyframe")
        R_anchor = self._rotation(state, anchor.t, t)
        m_anchor = None if R_anchor is None else self._matches(features, anchor.features, R_anchor)
        if m_anchor is None:
            return RestTest(False, "too few keypoints matched with the frame the rest began at", chi2=chi2,
                            chi2_threshold=threshold, disparity_px=disparity)
        # the gyroscope's rotation since the anchor is only as good as its bias: its scatter over the rest
        dt = t - anchor.t
        sigma_rot = gyro_rotation_sigma(self.factors.imu.window(min(anchor.t, t - s.gyro_bias_window_s), t), dt, s)
        fit = anchor_motion(m_anchor[0], m_anchor[1], camera, m_anchor[2], sigma_rot)
        if fit is None:
            return RestTest(False, "too few keypoints in front of the camera", chi2=chi2, chi2_threshold=threshold,
                            disparity_px=disparity)
        motion, sigmas = fit.distance, fit.sigmas_beyond(s.max_anchor_motion)
        figures = dict(chi2=chi2, chi2_threshold=threshold, disparity_px=disparity, anchor_motion=motion,
                       anchor_motion_sigmas=sigmas)
        if not sigmas <= s.anchor_motion_sigmas:
            return RestTest(False, f"moved {motion:.2%} of the scene's depth since frame {anchor.frame_id}, "
                                   f"{sigmas:.1f} sigma beyond {s.max_anchor_motion:.2%} (creeping)", **figures)
        self.anchor, self._rested = anchor, True
        T_i_c = invert_transform(self.factors.T_c_i)
        T_turn = np.eye(4)
        T_turn[:3, :3] = R_anchor  # the IMU turned about its origin since the anchor
        T_w_c = anchor.T_w_c @ self.factors.T_c_i @ T_turn @ T_i_c
        C = anchor.covariance + np.diag([s.rotation_random_walk ** 2 * dt] * 3
                                        + [s.translation_random_walk ** 2 * dt] * 3)
        return RestTest(True, f"at rest: IMU chi2 {chi2:.0f} <= {threshold:.0f} ({dof} dof), keypoints moved "
                              f"{disparity:.2f} px since the previous frame (rotation removed), the camera "
                              f"{motion:.2%} of the depth since frame {anchor.frame_id} ({sigmas:.1f} sigma beyond "
                              f"{s.max_anchor_motion:.2%}); position of frame "
                              f"{anchor.frame_id}", T_w_c, 0.5 * (C + C.T), chi2, threshold, disparity, motion, sigmas)

    def _new_anchor(self, keyframe: int, history: PoseHistory) -> RestAnchor | None:
        prev = self._previous
        T_kf_a, C, _ = history.relative(keyframe, prev[0])
        T_w_a = history.pose(prev[0])
        if T_kf_a is None or T_w_a is None:
            return None
        return RestAnchor(prev[0], prev[1], prev[2], T_w_a, C, keyframe)
