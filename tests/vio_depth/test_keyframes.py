import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.errors import UnknownNameError
from vio_core.geometry import make_transform
from vio_depth.keyframes import (
    PAIRING_PRESETS,
    Keyframe,
    KeyframeBuffer,
    Motion,
    PairingSettings,
    pairing_preset,
)


def test_motion_from_transform_measures_rotation_and_translation():
    R = Rotation.from_rotvec([0.0, np.radians(7.0), 0.0]).as_matrix()
    m = Motion.from_transform(make_transform(R, [0.3, 0.0, 0.4]))
    assert m.rotation_deg == pytest.approx(7.0, abs=1e-9)
    assert m.translation_m == pytest.approx(0.5, abs=1e-12)


@pytest.mark.parametrize(
    "rot_deg, trans_m, expected",
    [(6.0, 0.0, True), (0.0, 1.6, True), (4.9, 1.4, False), (5.0, 1.5, False)],
)
def test_paper_rule_rotation_or_translation_strictly_exceeds(rot_deg, trans_m, expected):
    settings = PairingSettings(min_rotation_deg=5.0, min_translation_m=1.5)
    assert Motion(rot_deg, trans_m).exceeds(settings) is expected


def test_keyframe_fraction_scales_both_thresholds():
    settings = PairingSettings(min_rotation_deg=5.0, min_translation_m=1.5, keyframe_fraction=0.5)
    assert Motion(0.0, 0.8).exceeds(settings, settings.keyframe_fraction)
    assert not Motion(2.0, 0.7).exceeds(settings, settings.keyframe_fraction)


def test_buffer_is_bounded_and_newest_first():
    buf = KeyframeBuffer(PairingSettings(buffer_size=3))
    for i in range(5):
        buf.push(Keyframe(frame=i, features=None))
    assert len(buf) == 3
    assert [kf.frame for kf in buf.newest_first()] == [4, 3, 2]
    assert buf.newest.frame == 4


def test_presets_by_name_with_overrides_and_unknown_names():
    assert pairing_preset("kitti") == PAIRING_PRESETS["kitti"]
    s = pairing_preset("indoor", min_translation_m=0.3, min_rotation_deg=None)
    assert s.min_translation_m == 0.3 and s.min_rotation_deg == PAIRING_PRESETS["indoor"].min_rotation_deg
    with pytest.raises(ValueError, match="indoor.*kitti") as info:
        pairing_preset("outdoorsy")
    assert isinstance(info.value, UnknownNameError)


def test_invalid_settings_rejected():
    with pytest.raises(ValueError):
        PairingSettings(min_translation_m=0.0)
    with pytest.raises(ValueError):
        PairingSettings(keyframe_fraction=1.5)


def test_most_certain_depth_per_keypoint_is_kept():
    from vio_depth.pipeline import most_certain_per_keypoint

    idx = np.array([7, 3, 7, 5, 3, 7])
    sigma = np.array([0.5, 0.2, 0.1, 0.3, 0.4, 0.9])
    keep = most_certain_per_keypoint(idx, sigma)
    assert sorted(idx[keep].tolist()) == [3, 5, 7]
    chosen = dict(zip(idx[keep].tolist(), sigma[keep].tolist()))
    assert chosen == {3: 0.2, 5: 0.3, 7: 0.1}
    assert len(most_certain_per_keypoint(np.zeros(0, int), np.zeros(0))) == 0
