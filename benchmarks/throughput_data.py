"""Data of ``benchmarks/bench_throughput.py``: rendered sequences cached on disk, their SIMULATED
disparity as ``.npy`` files, and "views" of them (first N frames, or a ping-pong over the
rendered frames for runs longer than the rendering) made of hard links, so that a
1000-frame run costs no rendering and almost no disk.

* ``street_kitti``: the bundled street sample's scene and drive, rendered at the KITTI size
  1242x375 (fx = fy = 721.5, as KITTI's rectified ``P_rect_02``), 12 Hz (the drive covers
  14.5 s; 150 frames at KITTI's 10 Hz would run past it), 150 frames.
* ``room_vga``: the room sample at 640x480 (fx = fy = 525, as TUM RGB-D / 7-Scenes), 120 frames.
* ``kitti_tiny``: the real KITTI raw slice of ``../shared/data`` (7 frames, 1242x375 PNG),
  ping-ponged; its disparity is SIMULATED from the projected LiDAR (LiDAR-densified).

Every disparity here is SIMULATED (``vio_depth.disparity.simulation``), written once as
float32 ``<stem>.npy`` so the timed runs read precomputed disparity files
(``--disparity-dir``), as a run on Depth Anything outputs saved beforehand would.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from vio_core.camera import Camera
from vio_depth.disparity import DisparitySettings, DisparitySpec, create_disparity_source, disparity_preset
from vio_depth.io import open_sequence
from vio_depth.io.depth_png import write_bytes_atomic, write_depth_png
from vio_depth.io.tables import write_tum_trajectory
from vio_depth.simulate.generate import camera_poses, sample_spec
from vio_depth.simulate.render import render_view
from vio_depth.simulate.scene_library import build_scene

ROOT = Path(__file__).resolve().parents[1]
KITTI_TINY = ROOT.parent / "shared" / "data" / "kitti_tiny" / "2011_09_26" / "2011_09_26_drive_0023_sync"
DEFAULT_CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "vio-depth" / "bench_throughput"

#: name -> (sample, camera, frame rate Hz, frames)
RENDERED = {
    "street_kitti": ("street", Camera(1242, 375, 721.5, 721.5, 620.5, 187.0), 12.0, 150),
    "room_vga": ("room", Camera(640, 480, 525.0, 525.0, 319.5, 239.5), 20.0, 120),
}
#: marker written last into a finished rendering (its content: what was rendered)
MARKER = "prepared.json"


def _describe(name: str) -> dict:
    sample, cam, rate, n = RENDERED[name]
    return {"sample": sample, "camera": [cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy],
            "frame_rate_hz": rate, "frames": n, "disparity": "simulated, sequence's own seed", "layout": 1}


def write_disparity_files(sequence, folder: Path, settings: DisparitySettings | None = None) -> None:
    """Every frame's SIMULATED disparity as ``folder/<stem>.npy`` (float32 (H, W))."""
    source = create_disparity_source(DisparitySettings() if settings is None else settings, sequence)
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(len(sequence)):
        frame = sequence[i]
        np.save(folder / f"{frame.stem}.npy", np.asarray(source(frame), dtype=np.float32))


class RenderingUnfinished(Exception):
    """The rendering budget ran out; calling again continues where it stopped."""


def _spec(name: str):
    sample, camera, rate, n = RENDERED[name]
    return replace(sample_spec(sample), name=name, camera=camera, frame_rate_hz=rate, n_frames=n)


def prepare_rendered(name: str, cache: Path, budget_s: float = 600.0, log=print) -> Path:
    """The rendered sequence ``name`` of :data:`RENDERED` under ``cache``, rendered on first use.

    Rendering is resumable: frames already on disk are kept, and after ``budget_s`` seconds
    it stops with :class:`RenderingUnfinished` (call again to continue), so no single call
    runs for long on a shared machine. Frames are rendered exactly as
    ``vio_depth.simulate.generate_sample`` does (same scene, trajectory, noise seeds); the
    folder holds a native sequence with ground-truth poses and depth (no IMU) and
    ``disparity/<stem>.npy``, the sequence's SIMULATED disparity.

    Returns the folder.
    """
    out = cache / name
    want = _describe(name)
    try:
        if json.loads((out / MARKER).read_text()) == want:
            return out
    except (OSError, ValueError):
        pass
    spec = _spec(name)
    n = spec.n_frames
    tmp = cache / f".{name}.rendering"
    for sub in ("images", "depth", "disparity"):
        (tmp / sub).mkdir(parents=True, exist_ok=True)
    t_frames = spec.frame_times(n)
    poses = camera_poses(spec, spec.make_trajectory(spec.seed), t_frames)
    scene = None
    start = time.perf_counter()
    log(f"rendering {name}: {n} frames of {spec.camera.width}x{spec.camera.height} into {out} (once; minutes)")
    for i in range(n):
        stem = f"{i:06d}"
        image, depth = tmp / "images" / f"{stem}.jpg", tmp / "depth" / f"{stem}.png"
        if image.is_file() and depth.is_file():
            continue
        if time.perf_counter() - start > budget_s:
            raise RenderingUnfinished(f"{name}: rendering budget of {budget_s:.0f} s used up at frame {i} of {n}; "
                                      "run again to continue")
        scene = build_scene(spec.scene, spec.scene_seed) if scene is None else scene
        view = render_view(scene, spec.camera, poses[i], settings=spec.render, noise_seed=[spec.seed, 3, i])
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(view.image, cv2.COLOR_RGB2BGR),
                               [cv2.IMWRITE_JPEG_QUALITY, spec.jpeg_quality])
        write_depth_png(depth, view.depth)
        write_bytes_atomic(image, buf.tobytes())  # the image last: it marks the frame as done
        if (i + 1) % 10 == 0:
            log(f"{name}: frame {i + 1}/{n} ({time.perf_counter() - start:.0f} s)")
    (tmp / "frames.txt").write_text("# timestamp image_path\n" + "".join(
        f"{t:.6f} images/{i:06d}.jpg\n" for i, t in enumerate(t_frames)))
    write_tum_trajectory(tmp / "poses.txt", t_frames, poses)
    c = spec.camera
    meta = {"format": "vio-depth-sequence", "version": 1, "name": name,
            "camera": {"width": c.width, "height": c.height, "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                       "dist": []},
            "frames": "frames.txt", "poses": "poses.txt", "depth": {"folder": "depth", "scale": 256.0},
            "disparity": DisparitySpec.simulated(spec.disparity_seed, disparity_preset("default")).to_json(),
            "metadata": {"simulated": True, "generator": "benchmarks/throughput_data.py", "scene": spec.scene,
                         "description": f"SIMULATED (rendered) {spec.scene} at {c.width}x{c.height}"}}
    (tmp / "sequence.json").write_text(json.dumps(meta, indent=2) + "\n")
    write_disparity_files(open_sequence(tmp), tmp / "disparity")
    (tmp / MARKER).write_text(json.dumps(want))
    shutil.rmtree(out, ignore_errors=True)
    os.rename(tmp, out)
    return out


def prepare_kitti_tiny(cache: Path) -> Path | None:
    """KITTI-tiny's SIMULATED (LiDAR-densified) disparity as ``.npy`` files under ``cache``;
    None when ``../shared/data`` is absent. Returns the disparity folder."""
    if not KITTI_TINY.is_dir():
        return None
    folder = cache / "kitti_tiny_disparity"
    seq = open_sequence(KITTI_TINY)
    if not all((folder / f"{seq.frame(i).stem}.npy").is_file() for i in range(len(seq))):
        write_disparity_files(seq, folder, DisparitySettings(source="simulated"))
    return folder


def pingpong(n_source: int, n: int) -> np.ndarray:
    """Indices ``0, 1, .., n_source-1, n_source-2, .., 1, 0, 1, ..`` (length ``n``): the camera
    drives the rendered path forth and back, so consecutive frames stay consistent."""
    if n_source < 2:
        return np.zeros(n, int)
    period = 2 * n_source - 2
    p = np.arange(n) % period
    return np.where(p < n_source, p, period - p)


def _link(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:  # another file system, or not allowed: a symbolic link
        os.symlink(os.path.abspath(src), dst)


def _image_path(sequence, index: int) -> Path:
    """The image file of frame ``index`` (native: ``image_paths``; KITTI raw: ``_images``)."""
    paths = getattr(sequence, "image_paths", None) or getattr(sequence, "_images")
    return Path(paths[index])


def make_view(sequence_dir: Path, disparity_dir: Path, n: int, out: Path, rate_hz: float = 10.0) -> Path:
    """A native sequence of ``n`` frames at ``out`` over the frames of ``sequence_dir`` (any
    format), ping-ponged when ``n`` exceeds them: images and ``disparity/<stem>.npy`` are
    links to the originals, poses are the originals' (ground-truth poses, no IMU, no
    ground-truth depth: a view is for timing, not for evaluation). Reused when present."""
    marker = out / MARKER
    want = {"source": str(sequence_dir), "disparity": str(disparity_dir), "frames": n, "rate_hz": rate_hz}
    try:
        if json.loads(marker.read_text()) == want:
            return out
    except (OSError, ValueError):
        pass
    seq = open_sequence(sequence_dir)
    frames = [seq.frame(i) for i in range(len(seq))]
    order = pingpong(len(frames), n)
    shutil.rmtree(out, ignore_errors=True)
    (out / "images").mkdir(parents=True)
    (out / "disparity").mkdir()
    times = np.arange(n) / rate_hz
    lines = ["# timestamp image_path"]
    for k, src in enumerate(order):
        f = frames[src]
        image = _image_path(seq, src)
        ext = image.suffix
        _link(image, out / "images" / f"{k:06d}{ext}")
        _link(disparity_dir / f"{f.stem}.npy", out / "disparity" / f"{k:06d}.npy")
        lines.append(f"{times[k]:.6f} images/{k:06d}{ext}")
    (out / "frames.txt").write_text("\n".join(lines) + "\n")
    write_tum_trajectory(out / "poses.txt", times, np.stack([frames[s].T_w_c for s in order]))
    c = seq.camera
    meta = {"format": "vio-depth-sequence", "version": 1, "name": out.name,
            "camera": {"width": c.width, "height": c.height, "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                       "dist": list(c.dist)},
            "frames": "frames.txt", "poses": "poses.txt",
            "metadata": {"view_of": str(sequence_dir), "pingpong": bool(n > len(frames))}}
    (out / "sequence.json").write_text(json.dumps(meta, indent=2) + "\n")
    marker.write_text(json.dumps(want))
    return out
