"""Is a disparity map usable for this frame? The per-frame content checks (never a silently wrong map).

Two kinds of fault, two answers (docs/safety.md):

* A map that is malformed (wrong shape or dtype, infinite values) is an input error:
  :func:`~vio_depth.disparity.base.check_disparity` raises, naming the file and frame.
* A well-formed map whose *content* cannot give depth is a per-frame status
  (``invalid_disparity``: no depth, no fallback, the run goes on), decided here:

  - fewer than ``min_valid_fraction`` of its pixels are finite (an all-NaN map included);
  - its finite pixels are all equal (an all-zero map): no depth ordering at all;
  - it is **inverted**: at the frame's metric points the disparity *falls* as the points
    get nearer (Spearman rank correlation between ``d`` and ``1/depth`` at most
    :data:`INVERTED_RANK_CORRELATION`, with at least :data:`MIN_POINTS_FOR_INVERSION`
    points). An affine-invariant disparity is an *increasing* map of the true disparity
    (``alpha > 0``), so such a map is a depth map or a negated disparity, and any fit or
    carried-over fit would turn near into far.

NaN pixels inside an otherwise valid map are invalid pixels, not an error: points on them
are not sampled (:func:`~vio_depth.rescale.sample_bilinear`), so the fit never sees them,
and the depth is NaN (0 in the PNG) there. Negative values are valid: a shift can make an
affine-invariant disparity negative, and it is never ``abs()``-ed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vio_core.checks import check_array, check_image

#: least fraction of finite pixels in a usable map (``DisparitySettings.min_valid_fraction``
#: default); maps measured: KITTI-tiny SIMULATED 65 %, 7-Scenes SIMULATED 80 %, samples 100 %
MIN_VALID_FRACTION = 0.10
#: a rank correlation between d and 1/depth at the points at or below this marks an inverted map
INVERTED_RANK_CORRELATION = -0.5
#: fewer points than this cannot show an inversion
MIN_POINTS_FOR_INVERSION = 10


@dataclass(frozen=True)
class DisparityCheck:
    """Outcome of :func:`check_map_content` / :func:`check_inversion`.

    Attributes:
        ok: the map may be used.
        valid_fraction: fraction of finite pixels (1.0 for the inversion check).
        reason: why not (empty when ok).
    """

    ok: bool
    valid_fraction: float = 1.0
    reason: str = ""


def check_map_content(disparity, min_valid_fraction: float = MIN_VALID_FRACTION,
                      max_pixels: int = 250_000) -> DisparityCheck:
    """Check the content of a well-formed ``disparity: (H, W)`` map (see the module docstring).

    The valid fraction is exact; the constancy test looks at a regular subsample of at most
    about ``max_pixels`` pixels plus the full min/max of the finite ones.
    """
    d = check_image("disparity", disparity)
    finite = np.isfinite(d)
    n_valid = int(finite.sum())
    fraction = n_valid / d.size if d.size else 0.0
    if n_valid == 0:
        return DisparityCheck(False, 0.0, "the disparity map has no valid (finite) pixel")
    if fraction < min_valid_fraction:
        return DisparityCheck(False, fraction, f"only {fraction:.1%} of the disparity map is valid "
                                               f"(< min_valid_fraction {min_valid_fraction:.0%})")
    values = d if n_valid == d.size else d[finite]  # the usual all-finite map: no masked copy
    lo, hi = float(values.min()), float(values.max())
    if not hi > lo:
        return DisparityCheck(False, fraction, f"every valid disparity pixel is {lo:g}: the map orders no depths")
    return DisparityCheck(True, fraction)


def rank_correlation(a, b) -> float:
    """Spearman rank correlation of ``a: (N,)`` and ``b: (N,)`` (ties get their mean rank); NaN if undefined."""
    a = check_array("a", a, (None,))
    b = check_array("b", b, (len(a),))
    if len(a) < 2:
        return float("nan")
    ra, rb = _ranks(a), _ranks(b)
    ra -= ra.mean()
    rb -= rb.mean()
    den = float(np.sqrt((ra * ra).sum() * (rb * rb).sum()))
    return float((ra * rb).sum() / den) if den > 0 else float("nan")


def _ranks(x: np.ndarray) -> np.ndarray:
    order = np.argsort(x, kind="mergesort")
    ranks = np.empty(len(x))
    ranks[order] = np.arange(len(x), dtype=np.float64)
    # mean rank of ties
    _, inverse, counts = np.unique(x, return_inverse=True, return_counts=True)
    sums = np.bincount(inverse, weights=ranks)
    return sums[inverse] / counts[inverse]


def check_inversion(d_points, depth_points) -> DisparityCheck:
    """Refuse a map whose disparity falls as the points get nearer.

    Args:
        d_points: (N,) disparity sampled at the points (finite).
        depth_points: (N,) metres, the points' metric depth (> 0).
    """
    d = check_array("d_points", d_points, (None,))
    z = check_array("depth_points", depth_points, (len(d),))
    ok = np.isfinite(d) & np.isfinite(z) & (z > 0)
    if int(ok.sum()) < MIN_POINTS_FOR_INVERSION:
        return DisparityCheck(True)
    rho = rank_correlation(d[ok], 1.0 / z[ok])
    if np.isfinite(rho) and rho <= INVERTED_RANK_CORRELATION:
        return DisparityCheck(False, 1.0, f"the disparity falls as the {int(ok.sum())} metric points get nearer "
                                          f"(rank correlation {rho:.2f}): an inverted map (a depth map, or a "
                                          "negated disparity?)")
    return DisparityCheck(True)
