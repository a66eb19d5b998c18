"""Data of ``benchmarks/bench_realtime.py``: each dataset as a timed stream of frames, loaded
lazily (one frame in memory at a time, loading not timed), with its IMU samples and the pose
source and pairing preset it is run with.

* ``asl_room`` -- ``--poses vio``: the generated ASL sample (:func:`vio_depth.simulate.asl.generate_asl_sample`,
  the room scene and trajectory at its native 512x384, 20 Hz, 200 Hz SIMULATED IMU), rendered
  once into the cache; SIMULATED disparity files: an affine map of the rendered true inverse
  depth (as tests/vio_depth/vio/test_vio_runs.py builds them). SIMULATED images.
* ``asl_loop`` -- ``--poses vio``: the room walked round its table in a closed loop
  (``generate_asl_sample(trajectory="loop")``), 400 frames (20 s at 20 Hz, 200 Hz SIMULATED
  IMU) at x1.46875 of 512x384 = **752x564** (EuRoC's width, more pixels than its 752x480: the
  stand-in for a moving 752x480 recording, which ``../shared/data`` lacks); SIMULATED images and
  disparity (the same affine map of the rendered true inverse depth). Long enough that the
  start is not the p99.
* ``euroc`` -- ``--poses vio``: the real EuRoC V1_01 still slice of ``../shared/data`` (752x480,
  20 Hz, real 200 Hz IMU); it has no depth, so its disparity is a SIMULATED smooth ramp (as
  ``benchmarks/compare_outputs.py``'s ``write_euroc_disparity``): only the pose / points path
  is exercised, the depth is meaningless.
* ``kitti_tiny`` -- ``--poses gt``: the real KITTI raw slice of ``../shared/data`` (1242x375, 7
  frames, OXTS poses), ping-ponged to ``--kitti-frames`` frames at 10 Hz, its SIMULATED
  (LiDAR-densified) disparity (``--disparity simulated``).
* ``street_kitti`` -- ``--poses gt``: the street sample's drive rendered at 1242x375, 12 Hz,
  150 frames, exact poses, SIMULATED disparity: ``benchmarks/throughput_data.py``'s rendering,
  shared with ``bench_throughput.py``'s cache (rendered on first use: minutes).

The depth network is excluded everywhere: disparity comes from files or memory.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from vio_core.camera import Camera
from vio_depth.disparity import DisparitySettings, FileDisparity, create_disparity_source
from vio_depth.frame import ImuData
from vio_depth.io import open_sequence

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
EUROC = SHARED / "euroc_v101_static"
KITTI_TINY = SHARED / "kitti_tiny" / "2011_09_26" / "2011_09_26_drive_0023_sync"
#: frames of the generated ASL sample (rendered once, 4 s at 20 Hz)
ASL_FRAMES = 80
ASL_MARKER = "prepared.json"
#: the room loop at EuRoC's width: frames and image size factor (752x564)
LOOP_FRAMES = 400
LOOP_SCALE = 752 / 512


@dataclass
class StreamData:
    """One dataset as a stream.

    Attributes:
        name: dataset name; ``description``: what it is (SIMULATED parts named).
        camera: intrinsics of the images.
        timestamps: (N,) seconds, increasing: the recorded frame times.
        load: ``load(i) -> (image (H, W, 3) uint8 RGB, disparity (H, W) float32)`` of frame i.
        T_w_c: (N, 4, 4) camera-to-world poses, metres (``gt`` datasets), or None.
        imu: the IMU samples and calibration (``vio`` datasets), or None.
        poses: the pose source it is run with (``gt`` or ``vio``); ``pairing``: pairing preset.
        pose_kind: what its poses are (:data:`vio_depth.poses.POSE_UNCERTAINTY_PRESETS` name).
        truth_T_w_c: (N, 4, 4) the true camera poses of a ``vio`` dataset (rendered: only
            evaluate the odometry), or None.
        true_depth: ``true_depth(disparity) -> (H, W) metres`` (0: none) where the disparity is an
            exact map of the true depth (the rendered ASL datasets: the inverse of
            :func:`_save_disparity`), else None.
    """

    name: str
    description: str
    camera: Camera
    timestamps: np.ndarray
    load: Callable[[int], tuple[np.ndarray, np.ndarray]]
    poses: str
    pairing: str
    T_w_c: np.ndarray | None = None
    imu: ImuData | None = None
    pose_kind: str = "exact"
    truth_T_w_c: np.ndarray | None = None
    true_depth: Callable[[np.ndarray], np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def size(self) -> str:
        return f"{self.camera.width}x{self.camera.height}"

    def truncated(self, n: int | None) -> "StreamData":
        if n is None or n >= len(self):
            return self
        return StreamData(self.name, self.description, self.camera, self.timestamps[:n], self.load, self.poses,
                          self.pairing, None if self.T_w_c is None else self.T_w_c[:n], self.imu, self.pose_kind,
                          None if self.truth_T_w_c is None else self.truth_T_w_c[:n], self.true_depth)


def _rgb(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    return np.repeat(image[:, :, None], 3, axis=2) if image.ndim == 2 else image


def _ready(folder: Path, want: dict) -> bool:
    """The rendering in ``folder`` was made with the settings ``want`` (its marker file says so)."""
    try:
        return json.loads((folder / ASL_MARKER).read_text()) == want
    except (OSError, ValueError):
        return False


def _save_disparity(path: Path, depth: np.ndarray) -> None:
    """SIMULATED disparity of a rendered ``depth: (H, W)`` metres (0: none): an affine map of the
    true inverse depth, ``2 / depth + 0.1``, float32 .npy at ``path``."""
    np.save(path, np.where(depth > 0, 2.0 / np.maximum(depth, 1e-6) + 0.1, 0.0).astype(np.float32))


def _depth_of_disparity(disparity: np.ndarray) -> np.ndarray:
    """The true depth (metres, 0: none) behind a disparity written by :func:`_save_disparity`."""
    return np.where(disparity > 0.1 + 1e-6, 2.0 / np.maximum(disparity - 0.1, 1e-6), 0.0)


# ----------------------------------------------------------------------------- the datasets
def asl_room(cache: Path, log=print) -> StreamData:
    """The generated ASL sample (room, SIMULATED), rendered into ``cache/asl_room`` on first use."""
    folder = cache / "asl_room"
    want = {"sample": "room", "frames": ASL_FRAMES, "scale": 1.0, "disparity": "2 / depth + 0.1", "layout": 1}
    if not _ready(folder, want):
        _render_asl(folder, log)
        (folder / ASL_MARKER).write_text(json.dumps(want))
    return _rendered("asl_room", "generated ASL sample: room, SIMULATED images, IMU and disparity (affine map of "
                     "the true inverse depth)", folder, "vio", "indoor", _depth_of_disparity)


def _rendered(name: str, label: str, folder: Path, poses: str, pairing: str,
              true_depth: Callable[[np.ndarray], np.ndarray] | None = None) -> StreamData:
    """A rendered sequence at ``folder`` with its disparity files in ``folder/disparity``; it
    streams its IMU under ``vio`` (its poses then only evaluate), its poses otherwise.
    ``true_depth``: the depth behind those disparity files (:attr:`StreamData.true_depth`)."""
    seq = open_sequence(folder)
    disparity = FileDisparity(folder / "disparity")
    frames = [seq[i] for i in range(len(seq))]
    poses_w_c = np.stack([f.T_w_c for f in frames])
    extra = {"imu": seq.imu, "truth_T_w_c": poses_w_c} if poses == "vio" else {"T_w_c": poses_w_c}
    return StreamData(name, label, seq.camera, np.array([f.timestamp for f in frames]),
                      lambda i: (_rgb(frames[i].image()), np.asarray(disparity(frames[i]), np.float32)),
                      poses, pairing, pose_kind=seq.pose_kind, true_depth=true_depth, **extra)


def _render_asl(folder: Path, log) -> None:
    from vio_depth.simulate.asl import generate_asl_sample
    from vio_depth.simulate.generate import camera_poses, sample_spec
    from vio_depth.simulate.render import render_depth
    from vio_depth.simulate.scene_library import build_scene

    log(f"rendering the ASL sample (room, {ASL_FRAMES} frames) into {folder} (once; a few minutes)")
    root = generate_asl_sample(folder, sample="room", n_frames=ASL_FRAMES)
    seq = open_sequence(root)
    spec = sample_spec("room")
    scene = build_scene(spec.scene, spec.scene_seed)
    T_w_c = camera_poses(spec, spec.make_trajectory(spec.seed), spec.frame_times(ASL_FRAMES))
    out = folder / "disparity"
    out.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(seq):
        _save_disparity(out / f"{frame.stem}.npy", render_depth(scene, seq.camera, T_w_c[i]))


def asl_loop(cache: Path, log=print) -> StreamData:
    """The room loop at 752x564 (SIMULATED), rendered into ``cache/asl_loop`` on first use."""
    from vio_depth.simulate.asl import generate_asl_sample

    folder = cache / "asl_loop"
    want = {"sample": "room", "trajectory": "loop", "frames": LOOP_FRAMES, "scale": LOOP_SCALE,
            "disparity": "2 / depth + 0.1", "layout": 1}
    if not _ready(folder, want):
        log(f"rendering the room loop ({LOOP_FRAMES} frames, 752x564) into {folder} (once; minutes)")
        root = generate_asl_sample(folder, sample="room", n_frames=LOOP_FRAMES, scale=LOOP_SCALE, trajectory="loop",
                                   depth_dir=folder / "depth")
        out = folder / "disparity"
        out.mkdir(parents=True, exist_ok=True)
        for frame in open_sequence(root):
            _save_disparity(out / f"{frame.stem}.npy", np.load(folder / "depth" / f"{frame.stem}.npy"))
        (folder / ASL_MARKER).write_text(json.dumps(want))
    return _rendered("asl_loop", "room loop at 752x564 (generated ASL): SIMULATED images, IMU and disparity (affine "
                     "map of the true inverse depth)", folder, "vio", "indoor", _depth_of_disparity)


def euroc(cache: Path, log=print) -> StreamData | None:
    """The real EuRoC still slice with a SIMULATED ramp disparity; None when absent."""
    if not EUROC.is_dir():
        return None
    seq = open_sequence(EUROC)
    cam = seq.camera
    rows = np.linspace(0.2, 1.0, cam.height, dtype=np.float32)[:, None]
    cols = np.linspace(0.0, 0.1, cam.width, dtype=np.float32)[None, :]
    ramp = (rows + cols).astype(np.float32)  # nearer at the bottom, as compare_outputs.write_euroc_disparity
    frames = [seq[i] for i in range(len(seq))]
    return StreamData("euroc", "EuRoC V1_01 still slice: real images and IMU, SIMULATED ramp disparity", cam,
                      np.array([f.timestamp for f in frames]), lambda i: (_rgb(frames[i].image()), ramp),
                      "vio", "indoor", imu=seq.imu, pose_kind=seq.pose_kind)


def kitti_tiny(cache: Path, log=print, n: int = 61) -> StreamData | None:
    """The real KITTI-tiny slice ping-ponged to ``n`` frames at 10 Hz, SIMULATED disparity; None when absent."""
    if not KITTI_TINY.is_dir():
        return None
    from throughput_data import pingpong

    seq = open_sequence(KITTI_TINY)
    source = create_disparity_source(DisparitySettings(source="simulated"), seq)
    frames = [seq[i] for i in range(len(seq))]
    disparities: dict[int, np.ndarray] = {}

    def load(k: int):
        i = int(order[k])
        if i not in disparities:  # 7 maps of 1242x375: kept (SIMULATED, costly to make)
            disparities[i] = np.asarray(source(frames[i]), np.float32)
        return _rgb(frames[i].image()), disparities[i]

    order = pingpong(len(frames), n)
    return StreamData("kitti_tiny", "KITTI raw 0023 (7 real frames ping-ponged, real OXTS poses), SIMULATED "
                      "LiDAR-densified disparity", seq.camera, np.arange(n) / 10.0, load, "gt", "kitti",
                      T_w_c=np.stack([frames[i].T_w_c for i in order]), pose_kind=seq.pose_kind)


def street_kitti(cache: Path, log=print) -> StreamData:
    """The street drive rendered at 1242x375 (SIMULATED), bench_throughput's cached rendering."""
    import throughput_data

    folder = throughput_data.prepare_rendered("street_kitti", throughput_data.DEFAULT_CACHE, budget_s=3600.0, log=log)
    return _rendered("street_kitti", "street drive rendered at the KITTI size: SIMULATED images, exact poses, "
                     "SIMULATED disparity", folder, "gt", "kitti")


#: name -> builder ``(cache, log) -> StreamData | None`` (None: the data are absent)
DATASETS = {"asl_room": asl_room, "asl_loop": asl_loop, "euroc": euroc, "kitti_tiny": kitti_tiny, "street_kitti": street_kitti}
