"""Depth networks that produce each frame's affine-invariant disparity.

:func:`load_depth_anything` reads real Depth Anything (V1 / V2) weights from disk -- a
transformers folder, an ONNX file or an original ``.pth`` -- and :class:`ModelDisparity`
makes the loaded model a disparity source for the pipeline. Importing this package
imports neither torch, transformers nor onnxruntime; loading a model does.
"""

from .depth_anything import (
    DepthAnythingModel,
    DepthAnythingSettings,
    ModelDisparity,
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
    "ModelDisparity",
    "hf_to_original_state_dict",
    "load_depth_anything",
    "network_input_size",
    "original_to_hf_state_dict",
    "preprocess_image",
    "resize_disparity",
]
