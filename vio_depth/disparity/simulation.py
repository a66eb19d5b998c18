"""SIMULATED affine-invariant disparity: a stand-in for Depth Anything computed from GT depth.

This is **not** a network prediction. It is a deterministic function of a ground-truth
depth map, a sequence seed, the frame index and the parameters below, built to have
the properties the rescaling method relies on and the imperfections it must survive:

1. true disparity ``q = 1 / depth`` (1/m) on valid pixels; ``q = 0`` where the depth is
   invalid (0 / NaN: sky, i.e. points at infinity);
2. **softened depth edges**: ``q_soft = GaussianBlur(q, edge_sigma_px)`` (OpenCV, reflected
   border). On a plane ``1/z`` is affine in the pixel coordinates, so the blur leaves
   planar regions unchanged and only acts across depth discontinuities;
3. **smooth low-frequency multiplicative distortion**:
   ``q_dist = q_soft * (1 + distortion * g(u, v))`` where ``g`` in [-1, 1] is a weighted
   mean of ``distortion_waves`` plane cosine waves with random directions, phases,
   weights in [0.5, 1] and wavelengths between ``min_wavelength`` and ``max_wavelength``
   times the image diagonal;
4. **per-frame affine normalisation** (so the true alpha, beta differ per frame, as for
   Depth Anything, whose output is only defined up to scale and shift):
   ``d = scale * q_dist + shift`` with ``peak ~ U(peak_range)``,
   ``shift = U(shift_fraction) * peak`` and ``scale = (peak - shift) / max(q_dist)``,
   so that the noise-free output spans ``[shift, peak]``; sky gets ``shift``, a small
   positive value;
5. **pixel noise**: ``+ N(0, (noise * peak)^2)`` i.i.d. per pixel; the result is clipped
   at 0 (Depth Anything outputs are non-negative) and returned as float32.

Away from depth edges the output therefore satisfies
``1/depth = alpha * d + beta`` with ``alpha = 1 / scale`` and ``beta = -shift / scale``
up to the relative distortion (at most ``distortion``) and the additive noise.

Random numbers come from ``numpy.random.default_rng([seed, frame_index])`` drawn in this
order: peak, shift fraction, then per wave (direction, wavelength, phase, weight),
then the (H, W) noise field, so a frame's disparity depends only on its depth map, the
seed, its index and the parameters.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import cv2
import numpy as np

from vio_core.checks import check_array
from vio_core.errors import InputError, SettingsError, lookup


@dataclass(frozen=True)
class DisparitySimulation:
    """Parameters of the SIMULATED disparity model (see the module docstring).

    Attributes:
        edge_sigma_px: Gaussian blur sigma in pixels softening depth edges (0 = none).
        distortion: maximum relative amplitude of the smooth multiplicative distortion
            (0.03 = +-3 %).
        distortion_waves: number of cosine waves summed into the distortion field.
        min_wavelength: shortest distortion wavelength, as a fraction of the image diagonal.
        max_wavelength: longest distortion wavelength, as a fraction of the image diagonal.
        noise: standard deviation of the additive pixel noise, as a fraction of the peak.
        peak_range: (low, high) range of the per-frame output maximum (noise-free).
        shift_fraction: (low, high) range of the per-frame shift (the value of sky /
            infinitely far points), as a fraction of the peak.
    """

    edge_sigma_px: float = 1.5
    distortion: float = 0.03
    distortion_waves: int = 3
    min_wavelength: float = 0.6
    max_wavelength: float = 2.0
    noise: float = 0.002
    peak_range: tuple[float, float] = (5.0, 20.0)
    shift_fraction: tuple[float, float] = (0.005, 0.03)

    def __post_init__(self):
        object.__setattr__(self, "peak_range", tuple(float(v) for v in self.peak_range))
        object.__setattr__(self, "shift_fraction", tuple(float(v) for v in self.shift_fraction))
        problems = []
        if not self.edge_sigma_px >= 0:
            problems.append("edge_sigma_px must be >= 0")
        if not 0 <= self.distortion < 1:
            problems.append("distortion must be in [0, 1)")
        if int(self.distortion_waves) != self.distortion_waves or self.distortion_waves < 0:
            problems.append("distortion_waves must be a non-negative integer")
        if not 0 < self.min_wavelength <= self.max_wavelength:
            problems.append("need 0 < min_wavelength <= max_wavelength")
        if not self.noise >= 0:
            problems.append("noise must be >= 0")
        if len(self.peak_range) != 2 or not 0 < self.peak_range[0] <= self.peak_range[1]:
            problems.append("peak_range must be (low, high) with 0 < low <= high")
        if len(self.shift_fraction) != 2 or not 0 <= self.shift_fraction[0] <= self.shift_fraction[1] < 1:
            problems.append("shift_fraction must be (low, high) with 0 <= low <= high < 1")
        if problems:
            raise SettingsError("disparity simulation: " + "; ".join(problems))

    def to_json(self) -> dict:
        """Plain-JSON dict of every parameter (tuples become lists)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_json(cls, data: dict) -> "DisparitySimulation":
        """Inverse of :meth:`to_json`; unknown keys raise SettingsError naming them."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise SettingsError(f"disparity simulation: unknown parameter(s) {', '.join(unknown)}; "
                             f"valid: {', '.join(sorted(names))}")
        return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in data.items()})


_PRESETS = {
    # Realistic: softened edges, +-3 % low-frequency distortion, 0.2 % noise.
    "default": DisparitySimulation(),
    # Exactly affine in 1/depth (only the per-frame scale and shift): for unit tests.
    "clean": DisparitySimulation(edge_sigma_px=0.0, distortion=0.0, noise=0.0),
    # Harder: wider edge halos, +-8 % distortion, 1 % noise.
    "hard": DisparitySimulation(edge_sigma_px=3.0, distortion=0.08, noise=0.01),
}


def disparity_presets() -> list[str]:
    """Names of the built-in :class:`DisparitySimulation` presets."""
    return sorted(_PRESETS)


def disparity_preset(name: str) -> DisparitySimulation:
    """The preset ``name`` ("default", "clean" or "hard").

    Raises:
        UnknownNameError: unknown name (lists the valid ones).
    """
    return lookup("disparity simulation preset", name, _PRESETS)


@dataclass(frozen=True)
class SimulatedDisparity:
    """A SIMULATED disparity map and its true per-frame affine parameters.

    Attributes:
        disparity: (H, W) float32 affine-invariant disparity (bigger = nearer), >= 0.
        scale: per-frame scale (disparity units per 1/m).
        shift: per-frame shift (disparity units), the value at infinite depth.
    """

    disparity: np.ndarray
    scale: float
    shift: float

    @property
    def alpha(self) -> float:
        """True alpha of ``1/depth = alpha * d + beta`` (m^-1 per disparity unit)."""
        return 1.0 / self.scale

    @property
    def beta(self) -> float:
        """True beta of ``1/depth = alpha * d + beta`` (1/m)."""
        return -self.shift / self.scale


def distortion_field(shape, rng: np.random.Generator, model: DisparitySimulation) -> np.ndarray:
    """Smooth field ``g: (H, W)`` float64 in [-1, 1] (weighted mean of plane cosine waves).

    Draws, per wave, direction, wavelength, phase and weight from ``rng`` in that order.
    Returns zeros when ``model.distortion_waves`` is 0.
    """
    h, w = int(shape[0]), int(shape[1])
    diag = float(np.hypot(h, w))
    v = np.arange(h, dtype=np.float64)[:, None]
    u = np.arange(w, dtype=np.float64)[None, :]
    total = np.zeros((h, w))
    weight_sum = 0.0
    for _ in range(int(model.distortion_waves)):
        theta = rng.uniform(0.0, np.pi)
        wavelength = rng.uniform(model.min_wavelength, model.max_wavelength) * diag
        phase = rng.uniform(0.0, 2.0 * np.pi)
        weight = rng.uniform(0.5, 1.0)
        k = 2.0 * np.pi / wavelength
        total = total + weight * np.cos(k * (np.cos(theta) * u + np.sin(theta) * v) + phase)
        weight_sum += weight
    return total / weight_sum if weight_sum > 0 else total


def simulate_disparity(depth, seed: int, frame_index: int,
                       model: DisparitySimulation | None = None) -> SimulatedDisparity:
    """SIMULATED affine-invariant disparity of one frame (see the module docstring).

    Args:
        depth: (H, W) metres ground-truth z-depth; 0, negative or NaN = invalid (sky).
        seed: non-negative sequence seed.
        frame_index: non-negative frame index; with ``seed`` it seeds the frame's RNG.
        model: parameters (default: the "default" preset).

    Returns:
        SimulatedDisparity with ``disparity: (H, W)`` float32 and the true scale/shift.
        When no pixel is valid, ``scale`` is 1.0 and every pixel is ``shift`` + noise.
    """
    depth = check_array("depth", depth, (None, None))
    if int(seed) < 0 or int(frame_index) < 0:
        raise InputError(f"seed and frame_index must be non-negative, got {seed}, {frame_index}")
    model = _PRESETS["default"] if model is None else model
    rng = np.random.default_rng([int(seed), int(frame_index)])
    peak = rng.uniform(*model.peak_range)
    shift = rng.uniform(*model.shift_fraction) * peak

    d64 = depth.astype(np.float64)
    valid = np.isfinite(d64) & (d64 > 0)
    q = np.zeros(d64.shape)
    q[valid] = 1.0 / d64[valid]
    if model.edge_sigma_px > 0:
        q = cv2.GaussianBlur(q, (0, 0), model.edge_sigma_px, borderType=cv2.BORDER_REFLECT)
    g = distortion_field(q.shape, rng, model)
    q = q * (1.0 + model.distortion * g)
    q_max = float(q.max()) if q.size else 0.0
    scale = (peak - shift) / q_max if q_max > 0 else 1.0
    d = scale * q + shift
    if model.noise > 0:
        d = d + (model.noise * peak) * rng.standard_normal(d.shape)
    d = np.maximum(d, 0.0).astype(np.float32)
    return SimulatedDisparity(d, float(scale), float(shift))
