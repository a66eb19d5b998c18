"""Depth Anything loaders (transformers folder, ONNX, original .pth) with tiny random models.

No real Depth Anything weights exist offline, so every loader is checked against a tiny
randomly initialised transformers ``DepthAnythingForDepthEstimation`` (DINOv2 width 32,
5 blocks, 2 heads): the loaded model must reproduce the network run directly. The
official architectures are checked on torch's "meta" device (shapes only, no memory).
"""

from __future__ import annotations

import socket

import numpy as np
import pytest

torch = pytest.importorskip("torch")
transformers = pytest.importorskip("transformers")

from vio_core.camera import Camera  # noqa: E402
from vio_core.errors import InputError, MissingDependencyError, SettingsError, ShapeError, UnknownNameError  # noqa: E402
from vio_depth.disparity import ModelDisparity
from vio_depth.frame import Frame  # noqa: E402
from vio_depth.models import (  # noqa: E402
    ARCHITECTURES,
    DepthAnythingArchitecture,
    DepthAnythingSettings,
    hf_to_original_state_dict,
    load_depth_anything,
    network_input_size,
    preprocess_image,
    resize_disparity,
)
from vio_depth.models.original_checkpoint import hf_config, resolve_architecture  # noqa: E402

IMAGE_HW = (70, 98)
SMALL = DepthAnythingSettings(input_size=42, device="cpu")  # 70 x 98 -> 42 x 56 network input
# the tiny network, written out independently of vio_depth's own config builder
TINY_ARCH = DepthAnythingArchitecture(
    name="tiny", hidden_size=32, num_layers=5, num_heads=2, out_indices=(2, 3, 4, 5),
    neck_hidden_sizes=(8, 16, 16, 32), fusion_hidden_size=16, head_hidden_size=8, image_size=98,
)


def _tiny_config(out_indices=(2, 3, 4, 5)):
    backbone = transformers.Dinov2Config(
        hidden_size=32, num_hidden_layers=5, num_attention_heads=2, patch_size=14, image_size=98,
        out_indices=list(out_indices), apply_layernorm=True, reshape_hidden_states=False,
    )
    return transformers.DepthAnythingConfig(
        backbone_config=backbone, reassemble_hidden_size=32, patch_size=14,
        neck_hidden_sizes=[8, 16, 16, 32], fusion_hidden_size=16, head_hidden_size=8,
    )


def _tiny_model(seed=0, out_indices=(2, 3, 4, 5)):
    """Tiny random network with O(1) weights, so its output is far from ReLU's zero."""
    torch.manual_seed(seed)
    model = transformers.DepthAnythingForDepthEstimation(_tiny_config(out_indices)).eval()
    with torch.no_grad():
        for name, p in model.named_parameters():
            if p.ndim > 1:
                p.normal_(0.0, 1.0 / np.sqrt(p[0].numel()))
            elif "norm" in name and name.endswith("weight"):
                p.normal_(1.0, 0.1)
            else:
                p.normal_(0.0, 0.1)
        model.head.conv3.bias.fill_(1.0)
    return model


def _image(seed=1):
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 256, (7, 10, 3)).astype(np.float32)
    import cv2

    smooth = cv2.resize(coarse, (IMAGE_HW[1], IMAGE_HW[0]), interpolation=cv2.INTER_LINEAR)
    noise = rng.normal(0, 8, smooth.shape)
    return np.clip(smooth + noise, 0, 255).astype(np.uint8)


def _direct(model, pixel_values, hw=IMAGE_HW):
    """The network run by hand on a preprocessed input, upsampled as the official code."""
    with torch.inference_mode():
        out = model(pixel_values=torch.from_numpy(pixel_values)).predicted_depth
        up = torch.nn.functional.interpolate(out[:, None], hw, mode="bilinear", align_corners=True)
    return up[0, 0].numpy()


def _assert_close(got, want, rtol):
    scale = float(np.abs(want).max())
    assert got.shape == want.shape
    assert np.abs(got - want).max() <= rtol * scale, np.abs(got - want).max() / scale


@pytest.fixture(scope="module")
def tiny():
    return _tiny_model()


@pytest.fixture(scope="module")
def hf_folder(tiny, tmp_path_factory):
    folder = tmp_path_factory.mktemp("tiny_hf")
    tiny.save_pretrained(folder)
    return folder


@pytest.fixture()
def no_hub(monkeypatch):
    """Any hub download or network connection fails the test."""
    import huggingface_hub
    import transformers.utils.hub as hf_utils_hub

    def refuse(*args, **kwargs):
        raise AssertionError("network / hub access attempted")

    for module in (huggingface_hub, huggingface_hub.file_download, hf_utils_hub):
        for name in ("hf_hub_download", "snapshot_download"):
            if hasattr(module, name):
                monkeypatch.setattr(module, name, refuse)
    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)


# ------------------------------------------------------------------------ preprocessing

def test_network_input_size_lower_bound_multiples_of_14():
    # hand-computed with the official rule (shorter side -> 518, round to x14, never < 518)
    assert network_input_size(480, 640) == (518, 686)  # transformers' conversion-check shape
    assert network_input_size(640, 480) == (686, 518)
    assert network_input_size(375, 1242) == (518, 1722)  # 1242 * 518 / 375 = 1715.6 -> 123 * 14
    assert network_input_size(70, 98) == (518, 728)  # small images are enlarged (725.2 -> 52 * 14)
    assert network_input_size(100, 100, input_size=20) == (28, 28)  # round gives 14 < 20 -> ceil
    for (h, w) in [(375, 1242), (480, 640), (1080, 1920), (70, 98), (333, 333), (1000, 200)]:
        nh, nw = network_input_size(h, w, 518)
        assert nh % 14 == 0 and nw % 14 == 0
        assert min(nh, nw) == 518 and max(nh, nw) >= 518
        scale = 518 / min(h, w)  # aspect ratio kept up to rounding to half a patch
        assert abs(nh - h * scale) <= 7 and abs(nw - w * scale) <= 7


def test_preprocess_image_normalises_rgb_channels_first():
    image = np.empty((70, 98, 3), np.uint8)
    image[...] = (200, 100, 30)  # bicubic keeps a constant image constant
    x = preprocess_image(image, input_size=42)
    assert x.shape == (1, 3, 42, 56) and x.dtype == np.float32
    want = (np.array([200, 100, 30]) / 255.0 - [0.485, 0.456, 0.406]) / [0.229, 0.224, 0.225]
    np.testing.assert_allclose(x[0].reshape(3, -1).mean(1), want, atol=1e-5)
    np.testing.assert_allclose(x[0].reshape(3, -1).std(1), 0.0, atol=1e-5)
    assert preprocess_image(image, size=(28, 70)).shape == (1, 3, 28, 70)
    # a textured image against the official image2tensor steps written out: / 255 (float64),
    # cv2 bicubic to the lower-bound size, ImageNet mean / std, channels first
    import cv2

    textured = _image()
    official = cv2.resize(textured / 255.0, (56, 42), interpolation=cv2.INTER_CUBIC)
    official = ((official - [0.485, 0.456, 0.406]) / [0.229, 0.224, 0.225]).transpose(2, 0, 1)[None]
    np.testing.assert_allclose(preprocess_image(textured, input_size=42), official, atol=1e-6)
    with pytest.raises(ShapeError, match="uint8"):
        preprocess_image(image.astype(np.float32))
    with pytest.raises(ShapeError):
        preprocess_image(image[..., 0])


@pytest.mark.parametrize("align_corners", [True, False])
def test_resize_disparity_matches_torch_bilinear(align_corners):
    d = np.random.default_rng(3).normal(size=(6, 9)).astype(np.float32)
    got = resize_disparity(d, 23, 40, align_corners=align_corners)
    want = torch.nn.functional.interpolate(torch.from_numpy(d)[None, None], (23, 40), mode="bilinear",
                                           align_corners=align_corners)[0, 0].numpy()
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-5)


def test_settings_reject_unknown_names():
    with pytest.raises(UnknownNameError, match="float32"):
        DepthAnythingSettings(dtype="bfloat16")
    with pytest.raises(UnknownNameError, match="cuda"):
        DepthAnythingSettings(device="tpu")
    with pytest.raises(SettingsError):
        DepthAnythingSettings(input_size=10)


# ------------------------------------------------------------------- transformers folder

def test_transformers_folder_matches_direct_run(tiny, hf_folder, no_hub):
    model = load_depth_anything(hf_folder, SMALL)
    assert model.kind == "transformers" and model.device == "cpu"
    image = _image()
    d = model.predict(image)
    assert d.shape == IMAGE_HW and d.dtype == np.float32 and np.isfinite(d).all()
    assert d.std() > 1e-3 * np.abs(d).mean()  # a real, non-constant map
    want = _direct(tiny, preprocess_image(image, input_size=42))
    _assert_close(d, want, 1e-5)


def test_transformers_folder_saved_with_transformers4_names(tiny, tmp_path, no_hub):
    # the published *-hf folders were saved by transformers 4.x (attention.attention.query ...)
    from safetensors.torch import load_file, save_file

    tiny.save_pretrained(tmp_path)
    renames = {"attention.q_proj": "attention.attention.query", "attention.k_proj": "attention.attention.key",
               "attention.v_proj": "attention.attention.value", "attention.o_proj": "attention.output.dense"}
    weights = {}
    for key, value in load_file(tmp_path / "model.safetensors").items():
        for new, old in renames.items():
            key = key.replace(new, old)
        weights[key] = value
    assert "backbone.encoder.layer.0.attention.attention.query.weight" in weights
    save_file(weights, tmp_path / "model.safetensors", metadata={"format": "pt"})
    image = _image(seed=2)
    d = load_depth_anything(tmp_path, SMALL).predict(image)
    _assert_close(d, _direct(tiny, preprocess_image(image, input_size=42)), 1e-5)


def test_transformers_folder_missing_weight_is_named(tiny, tmp_path, no_hub):
    from safetensors.torch import load_file, save_file

    tiny.save_pretrained(tmp_path)
    weights = load_file(tmp_path / "model.safetensors")
    del weights["head.conv3.bias"]
    save_file(weights, tmp_path / "model.safetensors", metadata={"format": "pt"})
    with pytest.raises(InputError, match=r"head\.conv3\.bias") as info:
        load_depth_anything(tmp_path, SMALL)
    assert str(tmp_path) in str(info.value)


def test_transformers_folder_errors(tiny, tmp_path, no_hub):
    with pytest.raises(InputError, match="config.json"):
        load_depth_anything(tmp_path, SMALL)
    (tmp_path / "config.json").write_text("{not json")
    with pytest.raises(InputError, match="config.json"):
        load_depth_anything(tmp_path, SMALL)
    tiny.save_pretrained(tmp_path)
    config = (tmp_path / "config.json").read_text()
    (tmp_path / "config.json").write_text(config.replace('"relative"', '"metric"'))
    with pytest.raises(InputError, match="metric"):
        load_depth_anything(tmp_path, SMALL)
    (tmp_path / "config.json").write_text(config.replace('"model_type": "depth_anything"', '"model_type": "dpt"'))
    with pytest.raises(InputError, match="'dpt'"):
        load_depth_anything(tmp_path, SMALL)
    (tmp_path / "config.json").write_text(config)
    (tmp_path / "model.safetensors").write_bytes(b"garbage" * 10)
    with pytest.raises(InputError, match=str(tmp_path)):
        load_depth_anything(tmp_path, SMALL)
    with pytest.raises(InputError, match="variant"):
        load_depth_anything(tmp_path, SMALL, variant="vits")
    with pytest.raises(InputError, match="float16"):
        load_depth_anything(tmp_path, DepthAnythingSettings(device="cpu", dtype="float16"))


# ------------------------------------------------------------------------------- ONNX

def _export_onnx(model, path, dynamic):
    pytest.importorskip("onnx")

    class Wrapper(torch.nn.Module):
        def __init__(self, inner):
            super().__init__()
            self.inner = inner

        def forward(self, pixel_values):
            return self.inner(pixel_values=pixel_values).predicted_depth

    axes = {"pixel_values": {2: "h", 3: "w"}, "predicted_depth": {1: "h", 2: "w"}} if dynamic else None
    # the TorchScript exporter: the dynamo one needs onnxscript, which is not installed
    torch.onnx.export(Wrapper(model).eval(), (torch.zeros(1, 3, 42, 56),), str(path), dynamo=False,
                      opset_version=17, input_names=["pixel_values"], output_names=["predicted_depth"],
                      dynamic_axes=axes)


@pytest.mark.filterwarnings("ignore")
def test_onnx_fixed_input_size_matches_torch(tiny, tmp_path):
    pytest.importorskip("onnxruntime")
    path = tmp_path / "tiny_fixed.onnx"
    _export_onnx(tiny, path, dynamic=False)
    model = load_depth_anything(path, DepthAnythingSettings(input_size=518, device="cpu"))
    assert model.kind == "onnx" and model.fixed_input_size == (42, 56)
    image = _image(seed=5)
    d = model.predict(image)  # input_size 518 is ignored: the model fixes 42 x 56
    assert d.shape == IMAGE_HW and d.dtype == np.float32
    want = _direct(tiny, preprocess_image(image, size=(42, 56)))
    _assert_close(d, want, 1e-4)


@pytest.mark.filterwarnings("ignore")
def test_onnx_dynamic_input_uses_depth_anything_resize(tiny, tmp_path):
    pytest.importorskip("onnxruntime")
    path = tmp_path / "tiny_dynamic.onnx"
    _export_onnx(tiny, path, dynamic=True)
    model = load_depth_anything(path, SMALL)
    assert model.fixed_input_size is None
    assert model.network_input_size(*IMAGE_HW) == (42, 56)
    image = _image(seed=6)
    _assert_close(model.predict(image), _direct(tiny, preprocess_image(image, input_size=42)), 1e-4)


def test_onnx_corrupt_and_missing_dependency(tmp_path, monkeypatch):
    pytest.importorskip("onnxruntime")
    path = tmp_path / "broken.onnx"
    path.write_bytes(b"\x08\x01garbage")
    with pytest.raises(InputError, match="broken.onnx"):
        load_depth_anything(path, SMALL)
    monkeypatch.setitem(__import__("sys").modules, "onnxruntime", None)
    with pytest.raises(MissingDependencyError, match=r"onnxruntime.*\[models\]"):
        load_depth_anything(path, SMALL)


# ------------------------------------------------------------------ original checkpoint

def _expected_original_keys(num_layers):
    """Key names of the original DepthAnything / DepthAnythingV2 modules, written by hand."""
    keys = {"pretrained.cls_token", "pretrained.pos_embed", "pretrained.mask_token",
            "pretrained.patch_embed.proj.weight", "pretrained.patch_embed.proj.bias",
            "pretrained.norm.weight", "pretrained.norm.bias"}
    for i in range(num_layers):
        for part in ("norm1", "attn.qkv", "attn.proj", "norm2", "mlp.fc1", "mlp.fc2"):
            keys |= {f"pretrained.blocks.{i}.{part}.weight", f"pretrained.blocks.{i}.{part}.bias"}
        keys |= {f"pretrained.blocks.{i}.ls1.gamma", f"pretrained.blocks.{i}.ls2.gamma"}
    head = [f"projects.{i}" for i in range(4)] + ["resize_layers.0", "resize_layers.1", "resize_layers.3"]
    head += [f"scratch.refinenet{i}.{part}" for i in range(1, 5)
             for part in ("out_conv", "resConfUnit1.conv1", "resConfUnit1.conv2",
                          "resConfUnit2.conv1", "resConfUnit2.conv2")]
    head += ["scratch.output_conv1", "scratch.output_conv2.0", "scratch.output_conv2.2"]
    for h in head:
        keys |= {f"depth_head.{h}.weight", f"depth_head.{h}.bias"}
    keys |= {f"depth_head.scratch.layer{i}_rn.weight" for i in range(1, 5)}
    return keys


def test_inverse_mapping_gives_original_names_and_tensors(tiny):
    hf = tiny.state_dict()
    original = hf_to_original_state_dict(hf)
    assert set(original) == _expected_original_keys(5)
    attn = "backbone.encoder.layer.0.attention."
    q, k, v = (hf[f"{attn}{n}.weight"] if f"{attn}{n}.weight" in hf else hf[f"{attn}attention.{m}.weight"]
               for n, m in (("q_proj", "query"), ("k_proj", "key"), ("v_proj", "value")))
    assert torch.equal(original["pretrained.blocks.0.attn.qkv.weight"], torch.cat([q, k, v]))
    # refinenet4 fuses the deepest features first: transformers' fusion layer 0
    assert torch.equal(original["depth_head.scratch.refinenet4.out_conv.weight"],
                       hf["neck.fusion_stage.layers.0.projection.weight"])
    assert torch.equal(original["depth_head.scratch.refinenet1.resConfUnit2.conv1.bias"],
                       hf["neck.fusion_stage.layers.3.residual_layer2.convolution1.bias"])
    assert torch.equal(original["depth_head.scratch.output_conv1.weight"], hf["head.conv1.weight"])
    assert torch.equal(original["depth_head.scratch.output_conv2.2.bias"], hf["head.conv3.bias"])
    assert torch.equal(original["depth_head.scratch.layer1_rn.weight"], hf["neck.convs.0.weight"])
    assert torch.equal(original["depth_head.resize_layers.3.weight"],
                       hf["neck.reassemble_stage.layers.3.resize.weight"])
    assert torch.equal(original["pretrained.blocks.4.ls2.gamma"],
                       hf["backbone.encoder.layer.4.layer_scale2.lambda1"])
    assert torch.equal(original["pretrained.pos_embed"], hf["backbone.embeddings.position_embeddings"])


def test_original_pth_reproduces_transformers_model(tiny, hf_folder, tmp_path):
    path = tmp_path / "tiny_depth_anything.pth"
    torch.save(hf_to_original_state_dict(tiny.state_dict()), path)
    model = load_depth_anything(path, SMALL, variant=TINY_ARCH)
    assert model.kind == "pth" and model.architecture == TINY_ARCH
    image = _image(seed=7)
    d = model.predict(image)
    np.testing.assert_allclose(d, load_depth_anything(hf_folder, SMALL).predict(image), rtol=0, atol=1e-6)
    # the same weights read with other encoder blocks feeding the head give another map
    other = DepthAnythingArchitecture(**{**TINY_ARCH.__dict__, "name": "tiny-v2", "out_indices": (1, 3, 4, 5)})
    assert np.abs(load_depth_anything(path, SMALL, variant=other).predict(image) - d).max() > 1e-3 * np.abs(d).max()


def test_original_pth_errors_name_the_file(tiny, tmp_path, monkeypatch):
    original = hf_to_original_state_dict(tiny.state_dict())
    missing = dict(original)
    del missing["depth_head.scratch.output_conv1.weight"]
    path = tmp_path / "missing.pth"
    torch.save(missing, path)
    with pytest.raises(InputError, match=r"missing\.pth.*head\.conv1\.weight"):
        load_depth_anything(path, SMALL, variant=TINY_ARCH)
    extra = {**original, "depth_head.scratch.extra.weight": torch.zeros(1)}
    torch.save(extra, path)
    with pytest.raises(InputError, match=r"unexpected.*depth_head\.scratch\.extra\.weight"):
        load_depth_anything(path, SMALL, variant=TINY_ARCH)
    wrong = DepthAnythingArchitecture(**{**TINY_ARCH.__dict__, "fusion_hidden_size": 24})
    torch.save(original, path)
    with pytest.raises(InputError, match="missing.pth"):
        load_depth_anything(path, SMALL, variant=wrong)
    path.write_bytes(b"not a pickle at all")
    with pytest.raises(InputError, match="missing.pth"):
        load_depth_anything(path, SMALL, variant=TINY_ARCH)
    with pytest.raises(InputError, match="does not exist"):
        load_depth_anything(tmp_path / "nowhere.pth", SMALL)
    (tmp_path / "weights.ckpt").write_bytes(b"x")
    with pytest.raises(InputError, match="unsupported"):
        load_depth_anything(tmp_path / "weights.ckpt", SMALL)
    torch.save(original, path)
    monkeypatch.setitem(__import__("sys").modules, "torch", None)
    with pytest.raises(MissingDependencyError, match=r"torch.*\[learned\]"):
        load_depth_anything(path, SMALL, variant=TINY_ARCH)


def _official_hf_config(encoder, version):
    """The transformers configs of the official checkpoints, as in transformers'
    convert_depth_anything_to_hf.py (written out independently of vio_depth)."""
    hidden, layers, heads, neck, fusion = {
        "vits": (384, 12, 6, [48, 96, 192, 384], 64),
        "vitb": (768, 12, 12, [96, 192, 384, 768], 128),
        "vitl": (1024, 24, 16, [256, 512, 1024, 1024], 256),
    }[encoder]
    if version == "v1":
        out = [layers - 3, layers - 2, layers - 1, layers]
    else:
        out = [5, 12, 18, 24] if encoder == "vitl" else [3, 6, 9, 12]
    backbone = transformers.Dinov2Config(
        hidden_size=hidden, num_hidden_layers=layers, num_attention_heads=heads, image_size=518,
        patch_size=14, out_indices=out, apply_layernorm=True, reshape_hidden_states=False,
    )
    return transformers.DepthAnythingConfig(
        backbone_config=backbone, reassemble_hidden_size=hidden, patch_size=14,
        neck_hidden_sizes=neck, fusion_hidden_size=fusion,
    )


@pytest.mark.parametrize("encoder, millions", [("vits", 24.8), ("vitb", 97.5), ("vitl", 335.3)])
def test_official_variants_inferred_from_shapes_and_file_name(encoder, millions):
    # build the official networks on the meta device: shapes only, no memory, no weights
    for version in ("v1", "v2"):
        with torch.device("meta"):
            reference = transformers.DepthAnythingForDepthEstimation(_official_hf_config(encoder, version))
            ours = transformers.DepthAnythingForDepthEstimation(hf_config(ARCHITECTURES[f"{version}-{encoder}"]))
        assert ours.config.backbone_config.out_indices == reference.config.backbone_config.out_indices
        ref_shapes = {k: tuple(v.shape) for k, v in reference.state_dict().items()}
        assert {k: tuple(v.shape) for k, v in ours.state_dict().items()} == ref_shapes
        # published parameter counts of the releases (Depth Anything V2 README)
        assert round(sum(p.numel() for p in ours.parameters()) / 1e6, 1) == millions
        shapes = {k: tuple(v.shape) for k, v in hf_to_original_state_dict(reference.state_dict()).items()}
        assert set(shapes) == _expected_original_keys(ours.config.backbone_config.num_hidden_layers)
        name = f"depth_anything_{encoder}14.pth" if version == "v1" else f"depth_anything_v2_{encoder}.pth"
        official = ARCHITECTURES[f"{version}-{encoder}"]
        assert resolve_architecture(shapes, name) == official
        assert resolve_architecture(shapes, name, encoder) == official
        assert resolve_architecture(shapes, "renamed.pth", f"{version}-{encoder}") == official
    with pytest.raises(InputError, match=f"v2-{encoder}"):
        resolve_architecture(shapes, "renamed.pth")
    with pytest.raises(InputError, match="requested"):
        resolve_architecture(shapes, name, "vitb" if encoder != "vitb" else "vits")
    with pytest.raises(UnknownNameError, match="v2-vitl"):
        resolve_architecture(shapes, name, "vitx")
    with pytest.raises(InputError, match="metric"):
        resolve_architecture(shapes, f"depth_anything_v2_metric_hypersim_{encoder}.pth")


# --------------------------------------------------------------------- disparity source

def test_model_disparity_source(hf_folder):
    model = load_depth_anything(hf_folder, SMALL)
    image = _image(seed=9)
    camera = Camera(IMAGE_HW[1], IMAGE_HW[0], 50.0, 50.0, 48.5, 34.5)
    frame = Frame(index=0, timestamp=0.0, stem="000000", camera=camera, T_w_c=None, load_image=lambda: image)
    source = ModelDisparity(model)
    assert source.kind == "model"
    d = source(frame)
    assert d.shape == IMAGE_HW and d.dtype == np.float32
    np.testing.assert_array_equal(d, model.predict(image))
    wrong = Frame(index=1, timestamp=0.1, stem="000001", camera=Camera(50, 40, 50.0, 50.0, 25.0, 20.0),
                  T_w_c=None, load_image=lambda: image)
    with pytest.raises(InputError, match="000001"):
        source(wrong)
