"""Shared primitives of every vio-depth layer: errors, array checks, the camera model, rigid transforms,
memoised chi-square quantiles.

The lowest layer: ``matchers``, ``triangulation`` and ``vio_depth`` import from here, and
this package imports none of them (tests/test_layering.py checks it).
"""

from .camera import Camera
from .checks import check_array, check_image, check_transform
from .environment import environ
from .errors import (
    CorruptImageError,
    InputError,
    MissingDependencyError,
    NumericalError,
    SequenceFormatError,
    SettingsError,
    ShapeError,
    UnknownNameError,
    VioDepthError,
    WorkerError,
    lookup,
)
from .geometry import (
    adjoint,
    adjoints,
    invert_transform,
    invert_transforms,
    make_transform,
    relative_transform,
    rotation_angle_deg,
    skew,
    skews,
    so3_exp,
    so3_log,
    transform_from_tum,
    transform_points,
    transform_to_tum,
)
from .npyfile import load_array
from .settings import Presets, override, require_positive, to_plain, toml_dumps, toml_loads
from .stats import chi2_quantile

__all__ = [
    "adjoint",
    "adjoints",
    "skews",
    "so3_exp",
    "so3_log",
    "Camera",
    "CorruptImageError",
    "environ",
    "Presets",
    "InputError",
    "MissingDependencyError",
    "NumericalError",
    "SequenceFormatError",
    "SettingsError",
    "ShapeError",
    "UnknownNameError",
    "VioDepthError",
    "WorkerError",
    "check_array",
    "chi2_quantile",
    "check_image",
    "check_transform",
    "invert_transform",
    "invert_transforms",
    "load_array",
    "lookup",
    "make_transform",
    "override",
    "require_positive",
    "relative_transform",
    "rotation_angle_deg",
    "skew",
    "to_plain",
    "toml_dumps",
    "toml_loads",
    "transform_from_tum",
    "transform_points",
    "transform_to_tum",
]
