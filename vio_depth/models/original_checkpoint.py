"""Original Depth Anything checkpoints (``.pth`` of the V1 / V2 GitHub releases).

The original repositories (LiheYoung/Depth-Anything, DepthAnything/Depth-Anything-V2)
save a plain state dict of ``DepthAnything`` / ``DepthAnythingV2``: a DINOv2 ViT encoder
under ``pretrained.*`` and a DPT head under ``depth_head.*``. vio-depth runs them with the
transformers implementation (``DepthAnythingForDepthEstimation``), so this module holds

* :class:`DepthAnythingArchitecture` and the official presets :data:`ARCHITECTURES`
  (``"v1-vits"`` ... ``"v2-vitl"``), with :func:`hf_config` turning one into a
  transformers config;
* :func:`resolve_architecture`, which infers the encoder size from the state-dict shapes
  and the version from the official file name (V1 and V2 have *identical* key names and
  shapes; they differ only in which encoder blocks feed the head);
* :func:`original_to_hf_state_dict` / :func:`hf_to_original_state_dict`, the key
  mapping of transformers' ``convert_depth_anything_to_hf.py`` (written out here since
  that script is not shipped in the wheel) and its inverse.

torch and transformers are imported lazily inside the functions that need them.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

from vio_core.errors import InputError, MissingDependencyError, UnknownNameError

#: version of the original release -> file-name pattern of its official checkpoints
_VERSION_FILE_PATTERNS = {
    "v1": re.compile(r"depth_anything_vit[sbl]14", re.IGNORECASE),
    "v2": re.compile(r"depth_anything_v2_vit[sblg]", re.IGNORECASE),
}
VERSIONS = tuple(_VERSION_FILE_PATTERNS)
ENCODERS = ("vits", "vitb", "vitl")


@dataclass(frozen=True)
class DepthAnythingArchitecture:
    """Shape of one Depth Anything network: a DINOv2 ViT encoder + a DPT head.

    Attributes:
        name: preset name, e.g. ``"v2-vitl"`` (free text for a custom architecture).
        hidden_size: ViT embedding width (384 / 768 / 1024 for ViT-S / B / L).
        num_layers: number of ViT blocks (12 / 12 / 24).
        num_heads: attention heads (6 / 12 / 16; 64 channels each).
        out_indices: 1-based indices of the blocks whose outputs feed the DPT head
            (transformers' ``out_indices``; the original code's ``intermediate_layer_idx``
            plus one). V1 uses the last four blocks, V2 spreads them over the depth.
        neck_hidden_sizes: the four DPT reassemble widths (original ``out_channels``).
        fusion_hidden_size: DPT fusion width (original ``features``).
        head_hidden_size: width of the last head convolution (32 in both releases).
        mlp_ratio: ViT MLP expansion (4).
        patch_size: ViT patch size in pixels (14).
        image_size: training resolution that sized the position embeddings (518 -> 37 x 37
            patches + class token).
    """

    name: str
    hidden_size: int
    num_layers: int
    num_heads: int
    out_indices: tuple[int, int, int, int]
    neck_hidden_sizes: tuple[int, int, int, int]
    fusion_hidden_size: int
    head_hidden_size: int = 32
    mlp_ratio: int = 4
    patch_size: int = 14
    image_size: int = 518

    def __post_init__(self):
        if len(self.out_indices) != 4 or len(self.neck_hidden_sizes) != 4:
            raise InputError(f"architecture {self.name}: out_indices and neck_hidden_sizes need 4 entries")
        if not all(1 <= i <= self.num_layers for i in self.out_indices) or len(set(self.out_indices)) != 4:
            raise InputError(
                f"architecture {self.name}: out_indices {self.out_indices} must be 4 distinct "
                f"blocks in 1..{self.num_layers}"
            )
        if self.hidden_size % self.num_heads:
            raise InputError(
                f"architecture {self.name}: hidden_size {self.hidden_size} not divisible by {self.num_heads} heads"
            )
        object.__setattr__(self, "out_indices", tuple(int(i) for i in self.out_indices))
        object.__setattr__(self, "neck_hidden_sizes", tuple(int(c) for c in self.neck_hidden_sizes))


def _official(version: str, encoder: str) -> DepthAnythingArchitecture:
    # encoder -> (hidden, blocks, heads, V1 out_indices, V2 out_indices, neck sizes, features);
    # V2's intermediate_layer_idx is {vits/vitb: [2, 5, 8, 11], vitl: [4, 11, 17, 23]}.
    table = {
        "vits": (384, 12, 6, (9, 10, 11, 12), (3, 6, 9, 12), (48, 96, 192, 384), 64),
        "vitb": (768, 12, 12, (9, 10, 11, 12), (3, 6, 9, 12), (96, 192, 384, 768), 128),
        "vitl": (1024, 24, 16, (21, 22, 23, 24), (5, 12, 18, 24), (256, 512, 1024, 1024), 256),
    }
    hidden, blocks, heads, v1_idx, v2_idx, neck, features = table[encoder]
    return DepthAnythingArchitecture(
        name=f"{version}-{encoder}", hidden_size=hidden, num_layers=blocks, num_heads=heads,
        out_indices=v1_idx if version == "v1" else v2_idx, neck_hidden_sizes=neck,
        fusion_hidden_size=features,
    )


#: official presets by name: "v1-vits", "v1-vitb", "v1-vitl", "v2-vits", "v2-vitb", "v2-vitl"
ARCHITECTURES: dict[str, DepthAnythingArchitecture] = {
    f"{v}-{e}": _official(v, e) for v in VERSIONS for e in ENCODERS
}
#: every accepted ``variant`` string: a preset name, or a bare encoder whose version is
#: read from the official file name
VARIANT_NAMES = tuple(sorted(ARCHITECTURES)) + ENCODERS


def hf_config(arch: DepthAnythingArchitecture):
    """transformers ``DepthAnythingConfig`` (relative-depth head) for ``arch``.

    Same settings as transformers' conversion script: DINOv2 backbone with
    ``apply_layernorm=True`` (the original ``get_intermediate_layers(norm=True)``) and
    ``reshape_hidden_states=False``.
    """
    try:
        from transformers import DepthAnythingConfig, Dinov2Config
    except ImportError:
        raise MissingDependencyError("transformers", "models", "loading Depth Anything weights") from None
    backbone = Dinov2Config(
        hidden_size=arch.hidden_size, num_hidden_layers=arch.num_layers,
        num_attention_heads=arch.num_heads, mlp_ratio=arch.mlp_ratio,
        patch_size=arch.patch_size, image_size=arch.image_size,
        out_indices=list(arch.out_indices), apply_layernorm=True,
        reshape_hidden_states=False, layerscale_value=1.0, layer_norm_eps=1e-6,
    )
    return DepthAnythingConfig(
        backbone_config=backbone, reassemble_hidden_size=arch.hidden_size,
        patch_size=arch.patch_size, neck_hidden_sizes=list(arch.neck_hidden_sizes),
        fusion_hidden_size=arch.fusion_hidden_size, head_hidden_size=arch.head_hidden_size,
        depth_estimation_type="relative",
    )


# ---------------------------------------------------------------------------- key mapping

#: transformers' names of a ViT block's attention projections, by transformers generation
#: (q, k, v, output projection), relative to ``backbone.encoder.layer.<i>.``
_HF_ATTENTION_NAMES = {
    "transformers>=5": ("attention.q_proj", "attention.k_proj", "attention.v_proj", "attention.o_proj"),
    "transformers<5": ("attention.attention.query", "attention.attention.key",
                       "attention.attention.value", "attention.output.dense"),
}


def hf_attention_names(hf_keys) -> tuple[str, str, str, str]:
    """The attention naming used by a transformers state dict (its keys ``hf_keys``)."""
    keys = set(hf_keys)
    for names in _HF_ATTENTION_NAMES.values():
        if f"backbone.encoder.layer.0.{names[0]}.weight" in keys:
            return names
    raise InputError(
        "unrecognised transformers Depth Anything layout: no query projection under "
        "backbone.encoder.layer.0 (supported: " + ", ".join(_HF_ATTENTION_NAMES) + ")"
    )


def _num_blocks(keys, pattern: str) -> int:
    found = {int(m.group(1)) for k in keys if (m := re.match(pattern, k))}
    return max(found) + 1 if found else 0


def _rename_pairs(num_layers: int, attention: tuple[str, str, str, str]) -> list[tuple[str, str]]:
    """(original key, transformers key) for every tensor except the fused qkv projections."""
    o_proj = attention[3]
    pairs = [
        ("pretrained.cls_token", "backbone.embeddings.cls_token"),
        ("pretrained.mask_token", "backbone.embeddings.mask_token"),
        ("pretrained.pos_embed", "backbone.embeddings.position_embeddings"),
        ("pretrained.patch_embed.proj.weight", "backbone.embeddings.patch_embeddings.projection.weight"),
        ("pretrained.patch_embed.proj.bias", "backbone.embeddings.patch_embeddings.projection.bias"),
        ("pretrained.norm.weight", "backbone.layernorm.weight"),
        ("pretrained.norm.bias", "backbone.layernorm.bias"),
    ]
    for i in range(num_layers):
        src, dst = f"pretrained.blocks.{i}", f"backbone.encoder.layer.{i}"
        pairs += [(f"{src}.ls{j}.gamma", f"{dst}.layer_scale{j}.lambda1") for j in (1, 2)]
        for p in ("weight", "bias"):
            pairs += [(f"{src}.norm{j}.{p}", f"{dst}.norm{j}.{p}") for j in (1, 2)]
            pairs += [(f"{src}.mlp.fc{j}.{p}", f"{dst}.mlp.fc{j}.{p}") for j in (1, 2)]
            pairs.append((f"{src}.attn.proj.{p}", f"{dst}.{o_proj}.{p}"))
    for i in range(4):
        for p in ("weight", "bias"):
            pairs.append((f"depth_head.projects.{i}.{p}", f"neck.reassemble_stage.layers.{i}.projection.{p}"))
            if i != 2:  # resize_layers.2 is an Identity (factor 1)
                pairs.append((f"depth_head.resize_layers.{i}.{p}", f"neck.reassemble_stage.layers.{i}.resize.{p}"))
        pairs.append((f"depth_head.scratch.layer{i + 1}_rn.weight", f"neck.convs.{i}.weight"))
    # refinenet4 fuses first (deepest features): transformers' fusion layer 0
    for i in range(1, 5):
        src, dst = f"depth_head.scratch.refinenet{i}", f"neck.fusion_stage.layers.{4 - i}"
        for p in ("weight", "bias"):
            pairs.append((f"{src}.out_conv.{p}", f"{dst}.projection.{p}"))
            for u in (1, 2):
                for c in (1, 2):
                    pairs.append((f"{src}.resConfUnit{u}.conv{c}.{p}", f"{dst}.residual_layer{u}.convolution{c}.{p}"))
    for p in ("weight", "bias"):
        pairs += [
            (f"depth_head.scratch.output_conv1.{p}", f"head.conv1.{p}"),
            (f"depth_head.scratch.output_conv2.0.{p}", f"head.conv2.{p}"),
            (f"depth_head.scratch.output_conv2.2.{p}", f"head.conv3.{p}"),
        ]
    return pairs


def original_to_hf_state_dict(state_dict: Mapping, attention: tuple[str, str, str, str]) -> dict:
    """Rename an original checkpoint's tensors to transformers' names.

    Args:
        state_dict: original keys (``pretrained.blocks.0.attn.qkv.weight`` ...) -> tensors.
        attention: transformers' attention names, from :func:`hf_attention_names` of the
            target model's state dict.

    Returns:
        A new dict; each fused ``attn.qkv`` (3C, C) is split into query, key and value
        (in that order). Keys the mapping does not know are kept unchanged so that a
        strict load reports them as unexpected.
    """
    out = dict(state_dict)
    n = _num_blocks(out, r"pretrained\.blocks\.(\d+)\.")
    for src, dst in _rename_pairs(n, attention):
        if src in out:
            out[dst] = out.pop(src)
    for i in range(n):
        for p in ("weight", "bias"):
            key = f"pretrained.blocks.{i}.attn.qkv.{p}"
            if key in out:
                qkv = out.pop(key)
                c = qkv.shape[0] // 3
                for j, name in enumerate(attention[:3]):
                    out[f"backbone.encoder.layer.{i}.{name}.{p}"] = qkv[j * c:(j + 1) * c]
    return out


def hf_to_original_state_dict(state_dict: Mapping) -> dict:
    """Inverse of :func:`original_to_hf_state_dict`: transformers names -> original names.

    The query, key and value projections are concatenated back into ``attn.qkv``. Useful
    to write an original-format ``.pth`` from a transformers model (tests do this).
    """
    import torch

    attention = hf_attention_names(state_dict)
    out = dict(state_dict)
    n = _num_blocks(out, r"backbone\.encoder\.layer\.(\d+)\.")
    for src, dst in _rename_pairs(n, attention):
        if dst in out:
            out[src] = out.pop(dst)
    for i in range(n):
        for p in ("weight", "bias"):
            keys = [f"backbone.encoder.layer.{i}.{name}.{p}" for name in attention[:3]]
            if all(k in out for k in keys):
                out[f"pretrained.blocks.{i}.attn.qkv.{p}"] = torch.cat([out.pop(k) for k in keys], 0)
    return out


# ------------------------------------------------------------------ variant resolution

def version_from_filename(path) -> str | None:
    """"v1" / "v2" from an official checkpoint file name, else None.

    ``depth_anything_vits14.pth`` (V1) and ``depth_anything_v2_vits.pth`` (V2).
    """
    name = Path(path).name
    for version, pattern in _VERSION_FILE_PATTERNS.items():
        if pattern.search(name):
            return version
    return None


def encoder_from_shapes(shapes: Mapping[str, tuple[int, ...]], path) -> str:
    """Official encoder ("vits" / "vitb" / "vitl") of an original state dict's shapes.

    Args:
        shapes: original key -> tensor shape.
        path: file name used in error messages.

    Raises:
        InputError: not an original Depth Anything state dict, or an encoder of no
            official size.
    """
    if "pretrained.cls_token" not in shapes:
        hint = ""
        if any(k.startswith("backbone.") for k in shapes):
            hint = " (it looks like a transformers state dict: point to the folder with its config.json)"
        raise InputError(f"{path}: not an original Depth Anything checkpoint: no 'pretrained.cls_token'{hint}")
    hidden = int(shapes["pretrained.cls_token"][-1])
    blocks = _num_blocks(shapes, r"pretrained\.blocks\.(\d+)\.")
    for encoder in ENCODERS:
        arch = ARCHITECTURES[f"v2-{encoder}"]
        if (arch.hidden_size, arch.num_layers) == (hidden, blocks):
            return encoder
    raise InputError(
        f"{path}: encoder with width {hidden} and {blocks} blocks matches no official size "
        f"({', '.join(ENCODERS)}); pass a DepthAnythingArchitecture as the variant"
    )


def resolve_architecture(shapes: Mapping[str, tuple[int, ...]], path,
                         variant: str | DepthAnythingArchitecture | None = None) -> DepthAnythingArchitecture:
    """The architecture of the original checkpoint at ``path`` with tensor ``shapes``.

    Args:
        shapes: original key -> tensor shape.
        path: the checkpoint's path (its file name tells V1 from V2).
        variant: None (infer everything), an encoder name ``"vits"``/``"vitb"``/``"vitl"``
            (checked against the shapes; the version still comes from the file name), a
            preset name such as ``"v2-vitl"`` (needed when the file was renamed), or a
            :class:`DepthAnythingArchitecture` for a non-official network (used as is).

    Raises:
        UnknownNameError: ``variant`` is not one of :data:`VARIANT_NAMES`.
        InputError: the file name is not an official one and no version was given, the
            shapes contradict ``variant``, or the file is a metric-depth checkpoint.
    """
    if "metric" in Path(path).name.lower():
        raise InputError(
            f"{path}: a metric-depth Depth Anything checkpoint predicts depth in metres, not the "
            "affine-invariant disparity vio-depth rescales; use a relative (disparity) checkpoint"
        )
    if isinstance(variant, DepthAnythingArchitecture):
        return variant
    if variant is not None and variant not in VARIANT_NAMES:
        raise UnknownNameError("Depth Anything variant", variant, VARIANT_NAMES)
    encoder = encoder_from_shapes(shapes, path)
    if variant is not None and variant in ARCHITECTURES:
        version, wanted = variant.split("-")
    else:
        version, wanted = version_from_filename(path), variant
        if version is None:
            raise InputError(
                f"{path}: cannot tell Depth Anything V1 from V2 (same keys and shapes) and the file "
                "name is not an official one (depth_anything_vit?14.pth / depth_anything_v2_vit?.pth); "
                f"name the variant explicitly, e.g. 'v2-{encoder}' or 'v1-{encoder}'"
            )
    if wanted is not None and wanted != encoder:
        raise InputError(f"{path}: the file holds a {encoder} encoder but variant {variant!r} was requested")
    return ARCHITECTURES[f"{version}-{encoder}"]
