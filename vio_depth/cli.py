"""``vio-depth`` command line.

    vio-depth run SEQ --out DIR [--matcher sift] [--max-frames N] [--disparity DIR] ...
    vio-depth presets
    vio-depth report OUT_DIR

Known errors (bad input, unknown names, missing optional packages) print one line on
stderr and exit with code 1; no traceback, no half-written output file.
"""

from __future__ import annotations

import argparse
import sys

from vio_core.errors import VioDepthError


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="vio-depth",
        description="Metric depth maps from affine-invariant disparity and triangulated metric points.",
    )
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="process a sequence and write metric depth maps")
    r.add_argument("sequence", help="sequence folder (native, KITTI raw drive, 7-Scenes or TUM RGB-D)")
    r.add_argument("--out", required=True, help="output folder (created if missing)")
    r.add_argument("--format", default=None, help="sequence format (default: auto-detect)")
    r.add_argument("--matcher", default="sift", help="matcher preset (see `vio-depth presets`; default: sift)")
    r.add_argument("--device", default=None, choices=["cpu", "cuda"],
                   help="device for learned matchers (default: cuda when available)")
    r.add_argument("--poses", default="gt", help="pose source: gt (sequence poses) or imu (gtsam preintegration)")
    r.add_argument("--pairing", default="kitti",
                   help="pair-selection preset: kitti (5 deg / 1.5 m), ddad (5 deg / 2 m), indoor (5 deg / 0.15 m)")
    r.add_argument("--min-rotation", type=float, default=None, metavar="DEG", help="override the rotation threshold")
    r.add_argument("--min-translation", type=float, default=None, metavar="M", help="override the translation threshold")
    r.add_argument("--points", default="sfm",
                   help="metric point source: sfm (default), or lidar:N / random:N sampled from ground truth")
    r.add_argument("--disparity", default=None, metavar="DIR",
                   help="read DIR/<image stem>.npy (float32 HxW affine-invariant disparity) instead of the "
                        "sequence's own; the word 'simulated' SIMULATES one from the ground-truth depth "
                        "(for evaluation on datasets without Depth Anything predictions)")
    r.add_argument("--model", default=None, metavar="PATH",
                   help="run Depth Anything V1/V2 (transformers folder, .onnx or original .pth) for the disparity")
    r.add_argument("--model-variant", default=None,
                   help="for a renamed .pth: vits/vitb/vitl or v1-vitl, v2-vits, ... (see docs/models.md)")
    r.add_argument("--model-input-size", type=int, default=518, metavar="PX",
                   help="Depth Anything input size (default 518)")
    r.add_argument("--max-frames", type=int, default=None, metavar="N", help="process only the first N frames")
    r.add_argument("--no-temporal", action="store_true", help="disable the Kalman filter on (alpha, beta)")
    r.add_argument("--no-backfill", action="store_true",
                   help="streaming behaviour only: no backward pass for the first frames that found no "
                        "earlier partner (see docs/design.md)")
    r.add_argument("--uncertainty", action="store_true",
                   help="also write uncertainty/<stem>.png: 1-sigma depth (metres x 256)")
    r.add_argument("--max-depth", type=float, default=80.0, help="depth cap for evaluation, metres (default 80)")
    r.add_argument("--seed", type=int, default=0, help="seed of RANSAC and random reference points")
    r.add_argument("--progress", dest="progress", action="store_true", default=None, help="force a progress bar")
    r.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    # --- issue 13: optional outputs (vio_depth.export) and the report (vio_depth.report) ---
    o = r.add_argument_group("optional outputs")
    o.add_argument("--save-npy", action="store_true",
                   help="also write depth_npy/<stem>.npy: float32 metres, NaN = invalid (exact, no 256 m cap)")
    o.add_argument("--save-preview", action="store_true",
                   help="also write preview/<stem>.png (colourised depth) and, with ground truth, "
                        "error/<stem>.png (signed relative error)")
    o.add_argument("--preview-range", default=None, metavar="MIN:MAX",
                   help="depth range of the preview colours in metres (default: one range per run)")
    o.add_argument("--preview-colormap", default="turbo", help="turbo (default), viridis, inferno, magma, plasma, cividis")
    o.add_argument("--save-ply", action="append", default=None, metavar="SPEC",
                   help="point clouds (PLY, world frame): sparse (per-frame points + merged map "
                        "ply/sparse_map.ply), dense[:STRIDE] (back-projected depth, every STRIDE-th pixel, default 4); "
                        "comma-separated or repeated")
    o.add_argument("--ply-frames", default=None, metavar="LIST",
                   help="frames that get dense clouds, e.g. 0,50,100 or 0:130:10 (default: all with depth)")
    o.add_argument("--report", action="store_true",
                   help="write thumbnails and the run report OUT/report/index.html (+ report.md); needs matplotlib")

    sub.add_parser("presets", help="list matcher, pairing, pose-source and format names")

    rep = sub.add_parser("report", help="write an HTML + Markdown report of a finished run")
    rep.add_argument("out_dir", help="the --out folder of a vio-depth run")
    rep.add_argument("--to", default=None, metavar="DIR", help="report folder (default: OUT_DIR/report)")
    return p


def _cmd_presets() -> int:
    from matchers import available_matchers

    from .io import available_formats
    from .keyframes import PAIRING_PRESETS
    from .poses import available_pose_sources

    print("matchers:     " + ", ".join(available_matchers()))
    print("pairing:      " + ", ".join(f"{k} ({v.min_rotation_deg:g} deg / {v.min_translation_m:g} m)"
                                        for k, v in PAIRING_PRESETS.items()))
    print("poses:        " + ", ".join(available_pose_sources()))
    print("formats:      " + ", ".join(available_formats()))
    print("points:       sfm, lidar:N, random:N")
    return 0


def _cmd_run(args) -> int:
    from .disparity import DisparityDirectory, SequenceDisparity
    from .io import open_sequence
    from .keyframes import pairing_preset
    from .pipeline import Pipeline, PipelineSettings
    from .poses import create_pose_source
    from .rescale import RescalerSettings
    from .run import format_table, run_sequence

    from matchers import available_matchers

    from vio_core.errors import UnknownNameError
    from .poses import available_pose_sources
    from .reference_points import parse_points_spec

    # Names and numbers first: a typo fails before any file is read or written.
    if args.disparity and args.model:
        raise _usage("--disparity and --model are mutually exclusive")
    if args.max_frames is not None and args.max_frames < 1:
        raise _usage("--max-frames must be >= 1")
    if args.matcher not in available_matchers():
        raise UnknownNameError("matcher", args.matcher, available_matchers())
    if args.poses not in available_pose_sources():
        raise UnknownNameError("pose source", args.poses, available_pose_sources())
    parse_points_spec(args.points)
    pairing = pairing_preset(args.pairing, min_rotation_deg=args.min_rotation, min_translation_m=args.min_translation)
    sequence = open_sequence(args.sequence, format=args.format)
    if args.disparity == "simulated":
        from .simulate.gt_disparity import GroundTruthSimulatedDisparity

        if not sequence.has_gt_depth:
            raise _usage(f"{sequence.root}: --disparity simulated needs ground-truth depth, which this sequence lacks")
        disparity = GroundTruthSimulatedDisparity(seed=args.seed)
    elif args.disparity:
        disparity = DisparityDirectory(args.disparity)
    elif args.model:
        from .models import DepthAnythingSettings, ModelDisparity

        disparity = ModelDisparity.from_path(args.model, DepthAnythingSettings(input_size=args.model_input_size,
                                                                               device=args.device),
                                             variant=args.model_variant)
    else:
        disparity = SequenceDisparity(sequence)
    pose_source = create_pose_source(args.poses, sequence)
    rescaler = RescalerSettings.default(seed=args.seed, temporal=not args.no_temporal)
    settings = PipelineSettings(matcher=args.matcher, device=args.device, pairing=pairing, rescaler=rescaler,
                                points=args.points, points_seed=args.seed)
    export = _export_settings(args)  # issue 13: bad flag values fail before anything is read
    if args.report:
        _require_matplotlib()
    # Check the first frame's inputs before anything is written.
    first = sequence[0]
    first.image()
    if isinstance(disparity, DisparityDirectory) and disparity(first) is None:
        raise _usage(f"{disparity.path_for(first)}: missing (expected one <image stem>.npy per frame)")
    pipeline = Pipeline(settings, pose_source, disparity)
    summary = run_sequence(sequence, pipeline, args.out, max_frames=args.max_frames, uncertainty=args.uncertainty,
                           max_eval_depth=args.max_depth, progress=args.progress,
                           backfill=not args.no_backfill, export=export)
    print(format_table(summary))
    if args.report:  # issue 13
        from .report import build_report

        result = build_report(args.out, run_info=_run_info(settings, args.argv))
        print(f"report: {result.html}")
    return 0


# --- issue 13: optional outputs and the report ------------------------------------------
def _export_settings(args):
    """:class:`vio_depth.export.ExportSettings` from the run flags (None when none is set)."""
    from .export import ExportSettings, PreviewSettings, parse_depth_range, parse_ply_spec

    if args.ply_frames is not None and not args.save_ply:
        raise _usage("--ply-frames needs --save-ply dense[:STRIDE]")
    style = PreviewSettings(colormap=args.preview_colormap,
                            depth_range=None if args.preview_range is None else parse_depth_range(args.preview_range))
    ply = parse_ply_spec(args.save_ply or [], frames=args.ply_frames)
    settings = ExportSettings(npy=args.save_npy, preview=style if args.save_preview else None, ply=ply,
                              thumbnails=args.report, preview_style=style)
    return settings if settings.any else None


def _require_matplotlib() -> None:
    import importlib.util

    from vio_core.errors import MissingDependencyError

    if importlib.util.find_spec("matplotlib") is None:
        raise MissingDependencyError("matplotlib", "report", "the run report (--report)")


def _run_info(settings, argv) -> dict:
    """Version, command line and settings of this run, for the report."""
    import dataclasses
    from importlib.metadata import PackageNotFoundError, version

    try:
        ver = version("vio-depth")
    except PackageNotFoundError:  # pragma: no cover - not installed
        ver = None
    return {"version": ver, "command_line": ["vio-depth"] + list(argv),
            "settings": dataclasses.asdict(settings)}


def _cmd_report(args) -> int:
    from .report import build_report

    result = build_report(args.out_dir, report_dir=args.to)
    print(f"report: {result.html} (and {result.markdown.name})")
    for note in result.omitted:
        print(f"  {note}")
    return 0


class _UsageError(VioDepthError):
    pass


def _usage(msg: str) -> _UsageError:
    return _UsageError(msg)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    args = _build_parser().parse_args(argv)
    args.argv = argv  # issue 13: the command line, for the report
    try:
        if args.command == "presets":
            return _cmd_presets()
        if args.command == "report":  # issue 13
            return _cmd_report(args)
        return _cmd_run(args)
    except VioDepthError as exc:
        print(f"vio-depth: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("vio-depth: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
