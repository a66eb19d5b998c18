"""Track bookkeeping from pairwise matches: growth, merges, conflicts, detach, removal."""

from __future__ import annotations

import numpy as np
import pytest

from vio_core.errors import InputError
from vio_depth.landmarks import FrameMatches, TrackTable


def _kp(n):
    return np.column_stack([np.arange(n, dtype=float), np.zeros(n)])


def _m(kf, a, b, conf=None):
    a, b = np.asarray(a), np.asarray(b)
    return FrameMatches(kf, a, b, np.ones(len(a)) if conf is None else np.asarray(conf, float))


def test_tracks_grow_along_a_chain():
    t = TrackTable()
    t.add_frame(0, _kp(5), [])
    t.add_frame(1, _kp(5), [_m(0, [0, 1, 2], [0, 1, 2])])
    t.add_frame(2, _kp(5), [_m(1, [0, 1], [0, 1]), _m(0, [0], [0])])
    obs = t.observations(min_length=3)
    assert len(np.unique(obs.track)) == 2  # keypoints 0 and 1 seen in all three frames
    for tr in np.unique(obs.track):
        assert sorted(obs.frame[obs.track == tr]) == [0, 1, 2]
    assert len(t.observations(min_length=2)) == 3 + 3 + 2
    assert t.frames == [0, 1, 2]


def test_keypoint_linking_two_tracks_merges_them():
    t = TrackTable()
    t.add_frame(0, _kp(3), [])
    t.add_frame(1, _kp(3), [])  # frames 0 and 1 were not matched with each other
    t.add_frame(2, _kp(3), [_m(0, [0], [1])])
    t.add_frame(3, _kp(3), [_m(1, [0], [2])])
    t.add_frame(4, _kp(3), [_m(2, [0], [0]), _m(3, [0], [0])])  # links the two tracks
    obs = t.observations(min_length=2)
    assert len(np.unique(obs.track)) == 1
    assert sorted(obs.frame) == [0, 1, 2, 3, 4]


def test_conflicting_tracks_are_not_merged():
    t = TrackTable()
    t.add_frame(0, _kp(3), [])
    t.add_frame(1, _kp(3), [_m(0, [0, 1], [0, 1])])  # two tracks, both in frames 0 and 1
    # a new keypoint matching both tracks (they share frames): the majority wins, no merge
    t.add_frame(2, _kp(3), [_m(0, [0], [0]), _m(1, [0], [1])])
    tracks = t.observations(min_length=1)
    assert len(np.unique(tracks.track[tracks.frame < 2])) == 2
    assert (tracks.frame == 2).sum() == 1


def test_two_keypoints_claiming_one_track_keep_the_better():
    t = TrackTable()
    t.add_frame(0, _kp(3), [])
    t.add_frame(1, _kp(3), [_m(0, [0], [0])])
    # keypoints 1 and 2 of frame 2 both match track of kp 0 (frames 0 and 1): kp 2 has two votes
    t.add_frame(2, _kp(3), [_m(0, [1, 2], [0, 0]), _m(1, [2], [0])])
    track_of = t.track_of(2)
    assert track_of[2] == t.track_of(0)[0]
    assert track_of[1] != track_of[2]


def test_associate_does_not_change_the_table():
    t = TrackTable()
    t.add_frame(0, _kp(4), [])
    t.add_frame(1, _kp(4), [_m(0, [0, 1, 2], [0, 1, 2])])
    before = t.observations()
    tracks = t.associate([_m(1, [3, 0], [0, 3])], n_keypoints=4)
    assert tracks[3] == t.track_of(1)[0] and tracks[0] == -1 and tracks[1] == -1
    after = t.observations()
    np.testing.assert_array_equal(before.track, after.track)


def test_detach_splits_and_remove_frame_forgets():
    t = TrackTable()
    t.add_frame(0, _kp(3), [])
    t.add_frame(1, _kp(3), [_m(0, [0, 1], [0, 1])])
    t.add_frame(2, _kp(3), [_m(1, [0, 1], [0, 1])])
    t.detach([2], [0])
    obs = t.observations(min_length=3)
    assert len(np.unique(obs.track)) == 1  # only keypoint 1's track still spans 3 frames
    t.remove_frame(0)
    assert t.frames == [1, 2] and 0 not in t
    assert set(t.observations().frame) == {1, 2}


def test_bad_inputs():
    t = TrackTable()
    t.add_frame(0, _kp(3), [])
    with pytest.raises(InputError):
        t.add_frame(0, _kp(3), [])
    with pytest.raises(InputError):
        t.add_frame(1, _kp(3), [_m(5, [0], [0])])  # unknown keyframe
    with pytest.raises(InputError):
        t.add_frame(1, _kp(3), [_m(0, [0], [7])])  # keypoint index out of range
