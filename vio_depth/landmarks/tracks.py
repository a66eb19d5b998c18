"""Feature tracks across the keyframes of a window, from pairwise matches.

Each keyframe keeps the keypoints it was given once (extracted once per frame); a track
is a set of (keyframe, keypoint) observations of one scene point, at most one per
keyframe. Tracks grow from the pairwise matches of a new keyframe with earlier ones:

* a new keypoint joins the track that most of its matches point to (ties: the larger
  summed match confidence);
* matched keypoints of earlier keyframes that belong to no track yet join that track too
  (or start a new one together with the new keypoint);
* when a keypoint's matches point to several tracks that never share a keyframe, they
  are **merged** (the keypoint links them); tracks that do share a keyframe conflict and
  are left apart;
* when two new keypoints claim the same track, the better supported one keeps it and
  the other starts a new track;
* :meth:`TrackTable.detach` splits an observation that disagrees with its track's
  geometry off into a track of its own (per-track outlier rejection happens in the
  window, which knows the poses).

Everything is numpy bookkeeping over the keyframes of the window: memory is bounded by
the number of keyframes kept times their keypoints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vio_core.checks import check_array
from vio_core.errors import InputError


@dataclass(frozen=True)
class FrameMatches:
    """Matches of one frame's keypoints with the keypoints of one keyframe of the table.

    Attributes:
        keyframe: frame id of the keyframe.
        idx_frame: (M,) int, keypoint indices in the frame.
        idx_keyframe: (M,) int, keypoint indices in the keyframe.
        confidence: (M,) in [0, 1], matching confidence (ones when unknown).
    """

    keyframe: int
    idx_frame: np.ndarray
    idx_keyframe: np.ndarray
    confidence: np.ndarray

    def __post_init__(self):
        a = check_array("idx_frame", self.idx_frame, (None,), dtype="int")
        check_array("idx_keyframe", self.idx_keyframe, (len(a),), dtype="int")
        check_array("confidence", self.confidence, (len(a),))

    def __len__(self) -> int:
        return len(self.idx_frame)

    @classmethod
    def from_matches(cls, keyframe: int, matches) -> "FrameMatches":
        """From a :class:`matchers.Matches` of (frame features, keyframe features)."""
        return cls(int(keyframe), np.asarray(matches.idx_a, np.int64), np.asarray(matches.idx_b, np.int64),
                   np.asarray(matches.confidence, np.float64))


@dataclass(frozen=True)
class Observations:
    """All observations of the table, one row each (grouped by keyframe, oldest first).

    Attributes:
        track: (M,) int track ids.
        frame: (M,) int keyframe ids.
        keypoint: (M,) int keypoint index in that keyframe.
        uv: (M, 2) raw pixels.
    """

    track: np.ndarray
    frame: np.ndarray
    keypoint: np.ndarray
    uv: np.ndarray

    def __len__(self) -> int:
        return len(self.track)

    def take(self, rows) -> "Observations":
        """The observations ``rows`` (a bool mask or indices), in order."""
        return Observations(self.track[rows], self.frame[rows], self.keypoint[rows], self.uv[rows])


class TrackTable:
    """Tracks over a bounded set of keyframes (see the module docstring)."""

    def __init__(self):
        self._next_id = 0
        self._track_of: dict[int, np.ndarray] = {}  # keyframe id -> (n_kp,) track id, -1 = none
        self._uv: dict[int, np.ndarray] = {}  # keyframe id -> (n_kp, 2) raw pixels

    # ------------------------------------------------------------------ queries
    @property
    def frames(self) -> list[int]:
        """Keyframe ids in insertion order."""
        return list(self._track_of)

    def __contains__(self, frame_id: int) -> bool:
        return frame_id in self._track_of

    def track_of(self, frame_id: int) -> np.ndarray:
        """(n_kp,) int: track id of each keypoint of a keyframe (-1 = none); a copy."""
        return self._track_of[frame_id].copy()

    def keypoints(self, frame_id: int) -> np.ndarray:
        """(n_kp, 2) raw pixels of a keyframe's keypoints."""
        return self._uv[frame_id]

    def observations(self, min_length: int = 1) -> Observations:
        """Every observation of tracks with at least ``min_length`` observations."""
        tr, fr, kp, uv = [], [], [], []
        for f, tracks in self._track_of.items():
            idx = np.nonzero(tracks >= 0)[0]
            tr.append(tracks[idx])
            fr.append(np.full(len(idx), f, np.int64))
            kp.append(idx)
            uv.append(self._uv[f][idx])
        if not tr:
            return Observations(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)))
        obs = Observations(np.concatenate(tr), np.concatenate(fr), np.concatenate(kp), np.concatenate(uv))
        if min_length > 1:
            _, inv, counts = np.unique(obs.track, return_inverse=True, return_counts=True)
            keep = counts[inv] >= min_length
            obs = Observations(obs.track[keep], obs.frame[keep], obs.keypoint[keep], obs.uv[keep])
        return obs

    # ------------------------------------------------------------------ association
    def _candidates(self, matches) -> tuple[np.ndarray, ...]:
        """Flattened matches: (frame kp, keyframe id, keyframe kp, confidence, track)."""
        a, k, b, c = [], [], [], []
        for m in matches:
            if m.keyframe not in self._track_of:
                raise InputError(f"tracks: frame {m.keyframe} is not a keyframe of the table")
            n_kp = len(self._track_of[m.keyframe])
            if len(m) and (m.idx_keyframe.min() < 0 or m.idx_keyframe.max() >= n_kp):
                raise InputError(f"tracks: keypoint index out of range for keyframe {m.keyframe}")
            a.append(np.asarray(m.idx_frame, np.int64))
            k.append(np.full(len(m), m.keyframe, np.int64))
            b.append(np.asarray(m.idx_keyframe, np.int64))
            c.append(np.asarray(m.confidence, np.float64))
        if not a:
            z = np.zeros(0, np.int64)
            return z, z, z, np.zeros(0), z
        a, k, b, c = (np.concatenate(x) for x in (a, k, b, c))
        t = np.full(len(a), -1, np.int64)
        for f in np.unique(k):
            sel = k == f
            t[sel] = self._track_of[int(f)][b[sel]]
        return a, k, b, c, t

    @staticmethod
    def _vote(a, t, c):
        """Per frame keypoint, its best track by (votes, confidence); returns (kp, track, votes, conf)."""
        has = t >= 0
        if not has.any():
            z = np.zeros(0, np.int64)
            return z, z, z, np.zeros(0)
        key = np.stack([a[has], t[has]], 1)
        pairs, inv = np.unique(key, axis=0, return_inverse=True)
        inv = inv.ravel()
        votes = np.bincount(inv, minlength=len(pairs))
        conf = np.bincount(inv, weights=c[has], minlength=len(pairs))
        order = np.lexsort((-conf, -votes, pairs[:, 0]))
        first = np.ones(len(order), bool)
        first[1:] = pairs[order[1:], 0] != pairs[order[:-1], 0]
        best = order[first]
        return pairs[best, 0], pairs[best, 1], votes[best], conf[best]

    @staticmethod
    def _unique_claims(kp, track, votes, conf) -> np.ndarray:
        """(K,) bool: the claim that keeps each track (most votes, then confidence)."""
        order = np.lexsort((-conf, -votes, track))
        keep = np.zeros(len(kp), bool)
        first = np.ones(len(order), bool)
        first[1:] = track[order[1:]] != track[order[:-1]]
        keep[order[first]] = True
        return keep

    def associate(self, matches, n_keypoints: int) -> np.ndarray:
        """Track id of each keypoint of a frame that is not in the table (-1 = none).

        Args:
            matches: :class:`FrameMatches` of the frame with keyframes of the table.
            n_keypoints: number of keypoints of the frame.

        Returns:
            (n_keypoints,) int. Nothing in the table changes.
        """
        out = np.full(int(n_keypoints), -1, np.int64)
        a, _, _, c, t = self._candidates(matches)
        if len(a) and a.max() >= n_keypoints:
            raise InputError("tracks: frame keypoint index out of range")
        kp, track, votes, conf = self._vote(a, t, c)
        keep = self._unique_claims(kp, track, votes, conf)
        out[kp[keep]] = track[keep]
        return out

    def add_frame(self, frame_id: int, keypoints, matches) -> np.ndarray:
        """Insert a keyframe and extend, create and merge tracks from its matches.

        Args:
            frame_id: new keyframe id (not yet in the table).
            keypoints: (N, 2) raw pixels of its keypoints.
            matches: :class:`FrameMatches` with keyframes already in the table.

        Returns:
            (N,) int: the track id of each of its keypoints (-1 = unmatched).
        """
        frame_id = int(frame_id)
        if frame_id in self._track_of:
            raise InputError(f"tracks: frame {frame_id} is already a keyframe of the table")
        uv = check_array("keypoints", keypoints, (None, 2)).astype(np.float64)
        n = len(uv)
        a, k, b, c, t = self._candidates(matches)
        if len(a) and a.max() >= n:
            raise InputError("tracks: frame keypoint index out of range")
        assigned = np.full(n, -1, np.int64)

        # 1. existing tracks: best-supported track per keypoint, one keypoint per track
        kp, track, votes, conf = self._vote(a, t, c)
        keep = self._unique_claims(kp, track, votes, conf)
        assigned[kp[keep]] = track[keep]

        # 2. merge other tracks a keypoint links to, when they never share a keyframe
        has = (t >= 0) & (assigned[a] >= 0) & (t != assigned[a])
        if has.any():
            for old, new in np.unique(np.stack([t[has], assigned[a[has]]], 1), axis=0):
                self._merge(int(old), int(new), assigned)

        # 3. unmatched keypoints with matches to track-less keyframe keypoints: new tracks
        free = t < 0
        starters = np.unique(a[free])
        starters = starters[assigned[starters] < 0]
        assigned[starters] = np.arange(self._next_id, self._next_id + len(starters))
        self._next_id += len(starters)

        # 4. track-less keyframe keypoints join the track of their new keypoint, at most
        #    one keypoint per (track, keyframe)
        if free.any():
            fa, fk, fb = a[free], k[free], b[free]
            ft = assigned[fa]
            ok = ft >= 0
            fa, fk, fb, ft = fa[ok], fk[ok], fb[ok], ft[ok]
            for f in np.unique(fk):
                f = int(f)
                sel = fk == f
                tracks_f = self._track_of[f]
                taken = np.isin(ft[sel], tracks_f[tracks_f >= 0])
                cand_b, cand_t = fb[sel][~taken], ft[sel][~taken]
                _, first_t = np.unique(cand_t, return_index=True)  # one keypoint per track
                cand_b, cand_t = cand_b[first_t], cand_t[first_t]
                _, first_b = np.unique(cand_b, return_index=True)  # one track per keypoint
                tracks_f[cand_b[first_b]] = cand_t[first_b]
        self._track_of[frame_id] = assigned
        self._uv[frame_id] = uv
        return assigned.copy()

    def _merge(self, old: int, new: int, pending: np.ndarray) -> None:
        """Relabel track ``old`` as ``new`` unless they share a keyframe."""
        frames_old = {f for f, tr in self._track_of.items() if np.any(tr == old)}
        frames_new = {f for f, tr in self._track_of.items() if np.any(tr == new)}
        if not frames_old or frames_old & frames_new or np.any(pending == old):
            return
        for f in frames_old:
            tr = self._track_of[f]
            tr[tr == old] = new

    # ------------------------------------------------------------------ edits
    def detach(self, frame_ids, keypoints) -> None:
        """Split observations off their tracks: each becomes a track of its own.

        Args:
            frame_ids: (K,) int keyframe ids.
            keypoints: (K,) int keypoint indices in those keyframes.
        """
        fr = check_array("frame_ids", frame_ids, (None,), dtype="int")
        kp = check_array("keypoints", keypoints, (len(fr),), dtype="int")
        for f in np.unique(fr):
            sel = kp[fr == f]
            tracks = self._track_of[int(f)]
            tracks[sel] = np.arange(self._next_id, self._next_id + len(sel))
            self._next_id += len(sel)

    def remove_frame(self, frame_id: int) -> None:
        """Forget a keyframe and its observations (tracks keep their other observations)."""
        self._track_of.pop(int(frame_id), None)
        self._uv.pop(int(frame_id), None)
