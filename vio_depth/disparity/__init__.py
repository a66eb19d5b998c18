"""Disparity stage: each frame's affine-invariant disparity, from files, a SIMULATION, or a network.

=================  ==========================================================================
module             job
=================  ==========================================================================
``base``           :class:`DisparitySource` protocol, :class:`DisparityKind`, :class:`DisparitySpec`
``sources``        :class:`FileDisparity`, :class:`SimulatedDisparitySource`
``model``          :class:`ModelDisparity` (Depth Anything, :mod:`vio_depth.models`)
``simulation``     the SIMULATED disparity model (:func:`simulate_disparity`)
``densify``        densifying sparse real ground truth before simulating
``registry``       :class:`DisparitySettings` and :func:`create_disparity_source`
``validity``       per-frame content checks: valid fraction, constant and inverted maps
``cache``          :class:`CachedDisparitySource`: each frame's map computed once, kept on disk
=================  ==========================================================================
"""

from .base import (
    DisparityKind,
    DisparitySource,
    DisparitySpec,
    ExplainsMissing,
    check_disparity,
    missing_disparity_reason,
)
from .cache import CachedDisparitySource, cache_key
from .densify import GtDisparitySettings, densify_depth, simulate_gt_disparity
from .model import ModelDisparity
from .registry import DISPARITY_CHOICES, DisparitySettings, create_disparity_source, source_for_spec
from .simulation import (
    DisparitySimulation,
    SimulatedDisparity,
    disparity_preset,
    disparity_presets,
    simulate_disparity,
)
from .sources import FileDisparity, SimulatedDisparitySource
from .validity import DisparityCheck, check_inversion, check_map_content, rank_correlation

__all__ = [
    "DISPARITY_CHOICES",
    "DisparityCheck",
    "CachedDisparitySource",
    "DisparityKind",
    "DisparitySettings",
    "DisparitySimulation",
    "DisparitySource",
    "DisparitySpec",
    "ExplainsMissing",
    "FileDisparity",
    "GtDisparitySettings",
    "ModelDisparity",
    "SimulatedDisparity",
    "SimulatedDisparitySource",
    "cache_key",
    "check_disparity",
    "check_inversion",
    "check_map_content",
    "create_disparity_source",
    "densify_depth",
    "disparity_preset",
    "disparity_presets",
    "missing_disparity_reason",
    "rank_correlation",
    "simulate_disparity",
    "simulate_gt_disparity",
    "source_for_spec",
]
