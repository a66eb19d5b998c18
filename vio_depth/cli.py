"""``vio-depth`` command line.

    vio-depth run SEQ --out DIR [--matcher sift] [--max-frames N] [--disparity DIR] ...
    vio-depth presets

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

    sub.add_parser("presets", help="list matcher, pairing, pose-source and format names")
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
    # Check the first frame's inputs before anything is written.
    first = sequence[0]
    first.image()
    if isinstance(disparity, DisparityDirectory) and disparity(first) is None:
        raise _usage(f"{disparity.path_for(first)}: missing (expected one <image stem>.npy per frame)")
    pipeline = Pipeline(settings, pose_source, disparity)
    summary = run_sequence(sequence, pipeline, args.out, max_frames=args.max_frames, uncertainty=args.uncertainty,
                           max_eval_depth=args.max_depth, progress=args.progress,
                           backfill=not args.no_backfill)
    print(format_table(summary))
    return 0


class _UsageError(VioDepthError):
    pass


def _usage(msg: str) -> _UsageError:
    return _UsageError(msg)


def main(argv=None) -> int:
    args = _build_parser().parse_args(argv)
    try:
        if args.command == "presets":
            return _cmd_presets()
        return _cmd_run(args)
    except VioDepthError as exc:
        print(f"vio-depth: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("vio-depth: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
