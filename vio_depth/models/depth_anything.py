"""Depth Anything (V1 / V2) as a disparity source: load real weights from disk, offline.

Three on-disk forms are recognised by :func:`load_depth_anything`:

* a **transformers folder** (``config.json`` + ``model.safetensors`` or
  ``pytorch_model.bin``, e.g. a download of ``depth-anything/Depth-Anything-V2-Small-hf``),
  loaded with ``AutoModelForDepthEstimation.from_pretrained(path, local_files_only=True)``;
* an **ONNX file** (``*.onnx``) run with onnxruntime; a fixed H x W input is honoured
  (the image is resized to it), a dynamic one gets Depth Anything's own resize;
* an **original checkpoint** (``*.pth`` of the official GitHub releases:
  ``depth_anything_vit{s,b,l}14.pth`` for V1, ``depth_anything_v2_vit{s,b,l}.pth`` for V2),
  renamed to transformers' layout (:mod:`.original_checkpoint`) and loaded strictly.

Every path verifies that each parameter came from the file (no missing, unexpected or
mis-shaped keys) and raises :class:`~vio_core.errors.InputError` naming the file
otherwise. Nothing is ever downloaded: the hub is never contacted.

:meth:`DepthAnythingModel.predict` returns Depth Anything's **relative disparity**
(bigger = nearer) at the image's own resolution. It is affine-invariant: it equals
``a / depth + b`` for an unknown scale ``a > 0`` and shift ``b`` per image, which is
exactly what :mod:`vio_depth.rescale` fits. It is *not* metric and not depth.

torch, transformers and onnxruntime are imported lazily; a missing one raises
:class:`~vio_core.errors.MissingDependencyError` naming the extra to install
(``models`` for transformers / onnxruntime, ``learned`` for torch).
"""

from __future__ import annotations

import contextlib
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vio_core.checks import check_image
from vio_core.environment import environ
from vio_core.errors import InputError, MissingDependencyError, SettingsError, UnknownNameError
from vio_core.limits import read_json_file

from .original_checkpoint import (
    DepthAnythingArchitecture,
    hf_attention_names,
    hf_config,
    original_to_hf_state_dict,
    resolve_architecture,
)
from .preprocess import network_input_size, preprocess_image, resize_disparity

DTYPES = ("float32", "float16")
#: file suffixes read as original (GitHub release) state dicts
ORIGINAL_SUFFIXES = (".pth", ".pt")
_HF_WEIGHT_FILES = ("model.safetensors", "model.safetensors.index.json",
                    "pytorch_model.bin", "pytorch_model.bin.index.json")


@dataclass(frozen=True)
class DepthAnythingSettings:
    """How a Depth Anything network is run.

    Attributes:
        input_size: pixels of the network input's shorter side (default 518, the
            training resolution of both releases). The image is resized keeping its
            aspect ratio so that both sides are multiples of 14 and at least
            ``input_size`` ("lower bound" policy, see
            :func:`~vio_depth.models.preprocess.network_input_size`), bicubic, ImageNet
            mean/std. Smaller values run faster with coarser disparity. Ignored by an
            ONNX model with a fixed input size.
        device: "cpu", "cuda" (or "cuda:<index>"), or None = CUDA when available, else CPU.
            Asking for CUDA where it is unavailable is an error, not a silent fallback.
        dtype: "float32" (default) or "float16" (CUDA only) for the torch paths. An ONNX
            model's input type is read from the model and this setting is ignored.
        upsample_align_corners: the network output is resized back to the image with
            bilinear interpolation; True as the official V2 ``infer_image`` (default),
            False as V1's ``run.py``.
    """

    input_size: int = 518
    device: str | None = None
    dtype: str = "float32"
    upsample_align_corners: bool = True

    def __post_init__(self):
        if not isinstance(self.input_size, (int, np.integer)) or self.input_size < 14:
            raise SettingsError(f"input_size must be an integer >= 14, got {self.input_size!r}")
        if self.device is not None and not re.fullmatch(r"cpu|cuda(:\d+)?", self.device):
            raise UnknownNameError("device", self.device, ["cpu", "cuda", "cuda:<index>"])
        if self.dtype not in DTYPES:
            raise UnknownNameError("dtype", self.dtype, DTYPES)


# ------------------------------------------------------------------ lazy dependencies

def _torch():
    try:
        import torch
    except ImportError:
        raise MissingDependencyError("torch", "learned", "running Depth Anything with torch") from None
    return torch


def _transformers():
    _torch()
    try:
        import transformers
    except ImportError:
        raise MissingDependencyError("transformers", "models", "loading Depth Anything weights") from None
    return transformers


def _onnxruntime():
    try:
        import onnxruntime
    except ImportError:
        raise MissingDependencyError("onnxruntime", "models", "running a Depth Anything ONNX model") from None
    return onnxruntime


# --------------------------------------------------------------------------- backends

class _TorchBackend:
    """A transformers ``DepthAnythingForDepthEstimation`` on one device and dtype."""

    def __init__(self, module, device: str, dtype: str):
        torch = _torch()
        self.torch = torch
        self.dtype = getattr(torch, dtype)
        self.device = device
        self.module = module.to(device=device, dtype=self.dtype).eval()

    def __call__(self, pixel_values: np.ndarray) -> np.ndarray:
        torch = self.torch
        with torch.inference_mode():
            x = torch.from_numpy(pixel_values).to(device=self.device, dtype=self.dtype)
            out = self.module(pixel_values=x).predicted_depth
            return out[0].float().cpu().numpy()


class _OnnxBackend:
    """An onnxruntime session with one (N, 3, H, W) input."""

    def __init__(self, session, path: Path, device: str):
        self.session = session
        self.device = device
        inputs = session.get_inputs()
        if len(inputs) != 1:
            raise InputError(f"{path}: expected one image input, the ONNX model has {[i.name for i in inputs]}")
        inp = inputs[0]
        shape = list(inp.shape)
        if len(shape) != 4 or (isinstance(shape[1], int) and shape[1] != 3):
            raise InputError(f"{path}: expected an (N, 3, H, W) input, got {inp.name} {shape}")
        types = {"tensor(float)": np.float32, "tensor(float16)": np.float16}
        if inp.type not in types:
            raise InputError(f"{path}: unsupported input type {inp.type} (expected float or float16)")
        h, w = shape[2], shape[3]
        fixed = [isinstance(s, int) and s > 0 for s in (h, w)]
        if fixed[0] != fixed[1]:
            raise InputError(f"{path}: input {inp.name} {shape} fixes only one of height/width; unsupported")
        self.fixed_size = (int(h), int(w)) if all(fixed) else None
        self.input_name = inp.name
        self.input_dtype = types[inp.type]
        self.output_name = session.get_outputs()[0].name
        self.path = path

    def __call__(self, pixel_values: np.ndarray) -> np.ndarray:
        out = self.session.run([self.output_name], {self.input_name: pixel_values.astype(self.input_dtype)})[0]
        out = np.asarray(out, dtype=np.float32)
        squeezed = out.reshape([s for s in out.shape if s != 1]) if out.ndim > 2 else out
        if squeezed.ndim != 2:
            raise InputError(f"{self.path}: output {self.output_name} has shape {out.shape}, expected (1, h, w)")
        return squeezed


# ---------------------------------------------------------------------------- model

class DepthAnythingModel:
    """A loaded Depth Anything network (see :func:`load_depth_anything`).

    Attributes:
        path: the weights it was loaded from.
        kind: "transformers", "onnx" or "pth".
        settings: the :class:`DepthAnythingSettings` it runs with.
        device: the resolved device ("cpu", "cuda", ...).
        fixed_input_size: (h, w) of a fixed-size ONNX model, else None.
        architecture: the :class:`DepthAnythingArchitecture` of a ``.pth``, else None.
        module: the torch module (transformers model) of the torch paths, else None.
    """

    def __init__(self, backend, path: Path, kind: str, settings: DepthAnythingSettings,
                 architecture: DepthAnythingArchitecture | None = None):
        self._backend = backend
        self.path = Path(path)
        self.kind = kind
        self.settings = settings
        self.device = backend.device
        self.fixed_input_size = getattr(backend, "fixed_size", None)
        self.architecture = architecture
        self.module = getattr(backend, "module", None)

    def __repr__(self) -> str:
        return f"DepthAnythingModel({str(self.path)!r}, kind={self.kind!r}, device={self.device!r})"

    def network_input_size(self, height: int, width: int) -> tuple[int, int]:
        """(h, w) pixels the network sees for a ``height`` x ``width`` image."""
        if self.fixed_input_size is not None:
            return self.fixed_input_size
        return network_input_size(height, width, self.settings.input_size)

    def preprocess(self, image) -> np.ndarray:
        """``image: (H, W, 3) uint8 RGB`` -> network input ``(1, 3, h, w)`` float32."""
        img = check_image("image", image, channels=3)
        return preprocess_image(img, self.settings.input_size, size=self.network_input_size(*img.shape[:2]))

    def predict(self, image) -> np.ndarray:
        """Relative disparity of ``image: (H, W, 3) uint8 RGB``: ``(H, W)`` float32.

        Bigger = nearer; affine-invariant (``a / depth + b`` with unknown ``a > 0``, ``b``
        per image), not metric. Depth Anything's preprocessing (see
        :meth:`preprocess`), one forward pass (torch under ``torch.inference_mode()``, or
        onnxruntime), then bilinear upsampling of the (h, w) output back to H x W.

        Raises:
            ShapeError: not an (H, W, 3) uint8 image.
        """
        pixel_values = self.preprocess(image)
        out = self._backend(pixel_values)
        h, w = np.asarray(image).shape[:2]
        return resize_disparity(out, h, w, align_corners=self.settings.upsample_align_corners)


# -------------------------------------------------------------------------- loading

def load_depth_anything(path, settings: DepthAnythingSettings | None = None, *,
                        variant: str | DepthAnythingArchitecture | None = None) -> DepthAnythingModel:
    """Load Depth Anything weights from ``path``, detecting their form.

    Args:
        path: a transformers folder (with ``config.json``), an ``.onnx`` file, or an
            original ``.pth``/``.pt`` state dict.
        settings: preprocessing / device / dtype (defaults: 518 px, auto device, float32).
        variant: only for an original ``.pth``: None (encoder from the tensor shapes,
            V1/V2 from the official file name), ``"vits"``/``"vitb"``/``"vitl"``, a preset
            ``"v1-vits"`` ... ``"v2-vitl"`` (for a renamed file), or a
            :class:`DepthAnythingArchitecture`.

    Raises:
        InputError: missing path, unreadable or corrupt file, an unsupported form, a
            metric-depth model, weights that do not fill the network exactly, or an
            unavailable device. The message names the file.
        UnknownNameError: unknown ``variant`` name.
        MissingDependencyError: torch / transformers / onnxruntime absent.
    """
    settings = settings or DepthAnythingSettings()
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: Depth Anything model path does not exist")
    if variant is not None and not (path.is_file() and path.suffix.lower() in ORIGINAL_SUFFIXES):
        raise InputError(f"{path}: a variant ({variant!r}) applies only to an original .pth checkpoint")
    if path.is_dir():
        return _load_transformers_folder(path, settings)
    suffix = path.suffix.lower()
    if suffix == ".onnx":
        return _load_onnx(path, settings)
    if suffix in ORIGINAL_SUFFIXES:
        return _load_original(path, settings, variant)
    raise InputError(
        f"{path}: unsupported Depth Anything model file; expected a transformers folder "
        f"(config.json + weights), an .onnx file, or an original {'/'.join(ORIGINAL_SUFFIXES)} checkpoint"
    )


def _resolve_torch_device(settings: DepthAnythingSettings, path: Path) -> str:
    torch = _torch()
    device = settings.device
    if device is None:
        device = "cuda" if torch.cuda.is_available() else "cpu"
    elif device.startswith("cuda") and not torch.cuda.is_available():
        raise InputError(f"{path}: device {device!r} requested but CUDA is not available to torch")
    if settings.dtype == "float16" and not device.startswith("cuda"):
        raise InputError(f"{path}: dtype float16 needs a CUDA device (got {device!r}); use float32 on CPU")
    return device


@contextlib.contextmanager
def _hub_offline():
    """Set HF_HUB_OFFLINE / TRANSFORMERS_OFFLINE for the duration of a load, then restore."""
    with environ({"HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}):
        yield


def _load_transformers_folder(path: Path, settings: DepthAnythingSettings) -> DepthAnythingModel:
    config_file = path / "config.json"
    if not config_file.is_file():
        raise InputError(f"{path}: not a transformers model folder (no config.json)")
    try:
        config = read_json_file(config_file, what="a model config.json")  # size and nesting checked first
    except (OSError, ValueError) as exc:
        raise InputError(f"{config_file}: cannot read the model config ({exc})") from None
    if not isinstance(config, dict) or config.get("model_type") != "depth_anything":
        found = config.get("model_type") if isinstance(config, dict) else None
        raise InputError(f"{config_file}: model_type is {found!r}, expected 'depth_anything'")
    if config.get("depth_estimation_type", "relative") != "relative":
        raise InputError(
            f"{config_file}: a {config['depth_estimation_type']!r} Depth Anything predicts depth in metres, "
            "not the affine-invariant disparity vio-depth rescales; use a relative model"
        )
    if not any((path / f).is_file() for f in _HF_WEIGHT_FILES):
        raise InputError(f"{path}: no weights file ({', '.join(_HF_WEIGHT_FILES)})")
    device = _resolve_torch_device(settings, path)
    transformers = _transformers()
    with _hub_offline():
        try:
            module, info = transformers.AutoModelForDepthEstimation.from_pretrained(
                str(path), local_files_only=True, output_loading_info=True
            )
        except Exception as exc:  # corrupt weights, bad config: whatever transformers raises
            raise InputError(f"{path}: cannot load the transformers model ({type(exc).__name__}: {exc})") from exc
    problems = {k: list(v) for k, v in info.items() if k != "error_msgs" and v}
    if info.get("error_msgs"):
        problems["error_msgs"] = list(info["error_msgs"])
    if problems:
        raise InputError(f"{path}: weights do not fill the model exactly: {_summarise(problems)}")
    return DepthAnythingModel(_TorchBackend(module, device, settings.dtype), path, "transformers", settings)


def _load_onnx(path: Path, settings: DepthAnythingSettings) -> DepthAnythingModel:
    ort = _onnxruntime()
    available = ort.get_available_providers()
    device = settings.device
    if device is None:
        device = "cuda" if "CUDAExecutionProvider" in available else "cpu"
    if device.startswith("cuda"):
        if "CUDAExecutionProvider" not in available:
            raise InputError(f"{path}: device {device!r} requested but onnxruntime has no CUDA provider")
        index = int(device.split(":")[1]) if ":" in device else 0
        providers = [("CUDAExecutionProvider", {"device_id": index}), "CPUExecutionProvider"]
    else:
        providers = ["CPUExecutionProvider"]
    try:
        session = ort.InferenceSession(str(path), providers=providers)
    except Exception as exc:  # onnxruntime raises its own (pybind) exception types
        raise InputError(f"{path}: cannot load the ONNX model ({type(exc).__name__}: {exc})") from None
    return DepthAnythingModel(_OnnxBackend(session, path, device), path, "onnx", settings)


def _load_original(path: Path, settings: DepthAnythingSettings,
                   variant: str | DepthAnythingArchitecture | None) -> DepthAnythingModel:
    torch = _torch()
    transformers = _transformers()
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle / zip / torch errors of a corrupt or foreign file
        raise InputError(f"{path}: cannot read a PyTorch state dict ({type(exc).__name__}: {exc})") from None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(f"{path}: expected a state dict (name -> tensor), got {type(state).__name__}")
    arch = resolve_architecture({k: tuple(v.shape) for k, v in state.items()}, path, variant)
    device = _resolve_torch_device(settings, path)
    with torch.device("meta"):  # no random init: every tensor is assigned from the file
        module = transformers.DepthAnythingForDepthEstimation(hf_config(arch))
    mapped = original_to_hf_state_dict(state, hf_attention_names(module.state_dict()))
    try:
        result = module.load_state_dict(mapped, strict=False, assign=True)
    except RuntimeError as exc:  # size mismatches
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip().startswith("size mismatch")]
        detail = "; ".join(lines[:3]) + (f" (+{len(lines) - 3} more)" if len(lines) > 3 else "") if lines else str(exc)
        raise InputError(f"{path}: weights do not fit Depth Anything {arch.name}: {detail}") from None
    problems = {}
    if result.missing_keys:
        problems["missing_keys"] = list(result.missing_keys)
    if result.unexpected_keys:
        problems["unexpected_keys"] = list(result.unexpected_keys)
    left = [n for n, t in [*module.named_parameters(), *module.named_buffers()] if t.is_meta]
    if left and not problems:
        problems["not_loaded"] = left
    if problems:
        raise InputError(f"{path}: weights do not fill Depth Anything {arch.name} exactly: {_summarise(problems)}")
    return DepthAnythingModel(_TorchBackend(module, device, settings.dtype), path, "pth", settings, arch)


def _summarise(problems: dict[str, list[str]], limit: int = 5) -> str:
    parts = []
    for kind, keys in problems.items():
        more = f" (+{len(keys) - limit} more)" if len(keys) > limit else ""
        parts.append(f"{kind}: {', '.join(map(str, keys[:limit]))}{more}")
    return "; ".join(parts)


# ------------------------------------------------------------------- disparity source
