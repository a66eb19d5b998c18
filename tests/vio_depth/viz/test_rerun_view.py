"""vio_depth.viz from a user's own loop: FrameStream results logged into a Rerun recording,
read back with rerun's own reader; a clear error without rerun-sdk."""

import sys

import numpy as np
import pytest

from vio_core.errors import MissingDependencyError
from vio_depth.pipeline import FrameStream, PipelineSettings
from vio_depth.viz import RerunView


def test_frame_stream_results_logged_and_read_back(tmp_path):
    pytest.importorskip("rerun")
    pytest.importorskip("skimage")
    from rerun.chunk import RrdReader

    from vio_depth.io import open_sequence
    from vio_depth.simulate.asl import generate_asl_sample
    from vio_depth.simulate.generate import sample_spec
    from vio_depth.simulate.render import render_depth
    from vio_depth.simulate.scene_library import build_scene

    seq = open_sequence(generate_asl_sample(tmp_path / "asl", n_frames=8, scale=0.5))
    spec = sample_spec("room")
    scene = build_scene(spec.scene, spec.scene_seed)
    stream = FrameStream(seq.camera, PipelineSettings.from_presets(pairing="indoor"))
    view = RerunView(save=tmp_path / "stream.rrd")
    with_depth = set()
    for frame in seq:
        depth = render_depth(scene, seq.camera, frame.T_w_c)
        disparity = np.where(depth > 0, 2.0 / np.maximum(depth, 1e-6) + 0.1, 0.0).astype(np.float32)  # SIMULATED
        image = frame.image()
        result = stream.push(image, disparity, timestamp=frame.timestamp, T_w_c=frame.T_w_c)
        view.log(result, image, seq.camera, T_w_c=frame.T_w_c, gt_depth=depth)
        if result.depth is not None:
            with_depth.add(frame.index)
    view.close()
    assert view.frames_logged == len(seq) and with_depth
    frames: dict = {}
    for chunk in RrdReader(tmp_path / "stream.rrd").stream().to_chunks():
        if "frame" in chunk.timeline_names:
            frames.setdefault(str(chunk.entity_path), set()).update(chunk.to_record_batch().column("frame").to_pylist())
    assert frames["/world/camera/image"] == set(range(len(seq)))
    assert frames["/world/camera/depth"] == with_depth == frames["/world/camera/error"]


def test_without_rerun_sdk_the_error_says_how_to_install_it(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` now fails
    with pytest.raises(MissingDependencyError, match=r"rerun-sdk.*pip install -e '\.\[viz\]'"):
        RerunView(save=tmp_path / "x.rrd")
