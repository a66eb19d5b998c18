"""Depth networks that produce each frame's affine-invariant disparity.

:func:`load_depth_anything` reads real Depth Anything (V1 / V2) weights from disk -- a
transformers folder, an ONNX file or an original ``.pth``;
:class:`vio_depth.disparity.ModelDisparity` makes a loaded model a disparity source. Importing this package
imports neither torch, transformers nor onnxruntime; loading a model does.
"""

from .depth_anything import (
    DepthAnythingModel,
    DepthAnythingSettings,
    load_depth_anything,
)
from .original_checkpoint import (
    ARCHITECTURES,
    VARIANT_NAMES,
    DepthAnythingArchitecture,
    hf_to_original_state_dict,
    original_to_hf_state_dict,
)
from .preprocess import network_input_size, preprocess_image, resize_disparity

__all__ = [
    "ARCHITECTURES",
    "VARIANT_NAMES",
    "DepthAnythingArchitecture",
    "DepthAnythingModel",
    "DepthAnythingSettings",
    "hf_to_original_state_dict",
    "load_depth_anything",
    "network_input_size",
    "original_to_hf_state_dict",
    "preprocess_image",
    "resize_disparity",
]
