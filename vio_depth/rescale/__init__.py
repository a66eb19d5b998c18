"""Rescaling stage: sparse metric points + an affine-invariant disparity map -> metric depth.

Model (the paper's Method section): ``1/D = alpha * d + beta`` with ``alpha > 0``, fitted per
image by a robust regression against the points' metric disparity ``1/depth``.

=====================  =====================================================================
module                 job
=====================  =====================================================================
``sampling``           read the disparity map at the points' sub-pixel positions
``affine``             the model's settings (:class:`RansacSettings`), result (:class:`AffineFit`)
``fit``                :func:`fit_affine` (MSAC + IRLS) and :func:`fit_scale_only`
``msac``               the vectorised machinery both fits share (internal)
``depthmap``           dense metric depth, its 1-sigma and the expected error from a fit
``temporal``           the Kalman filter across frames
``rescaler``           the streaming :class:`Rescaler`: fit, fallbacks, filter
=====================  =====================================================================
"""

from .affine import AffineFit, FitStatus, RansacSettings, metric_disparity_sigma
from .depthmap import depth_sigma_map, expected_relative_error, metric_depth, predicted_relative_error
from .fit import fit_affine, fit_scale_only, shared_depth_errors
from .rescaler import (
    RESCALER_PRESETS,
    FitSource,
    Rescaler,
    RescaleResult,
    RescalerSettings,
)
from .sampling import disparity_spread, sample_bilinear
from .temporal import AffineKalmanFilter, KalmanEstimate, KalmanSettings

__all__ = [
    "RESCALER_PRESETS",
    "AffineFit",
    "AffineKalmanFilter",
    "FitSource",
    "FitStatus",
    "KalmanEstimate",
    "KalmanSettings",
    "RansacSettings",
    "RescaleResult",
    "Rescaler",
    "RescalerSettings",
    "depth_sigma_map",
    "expected_relative_error",
    "fit_affine",
    "fit_scale_only",
    "metric_depth",
    "metric_disparity_sigma",
    "predicted_relative_error",
    "disparity_spread",
    "sample_bilinear",
    "shared_depth_errors",
]
