"""``vio-depth`` command line.

    vio-depth run SEQ --out DIR [--config FILE] [--matcher sift] [--pairing indoor] ...
    vio-depth config [--config FILE] [settings flags] --dump
    vio-depth presets
    vio-depth report OUT_DIR
    vio-depth eval SEQ[@OPTIONS]... --out DIR [--variants paper] [--studies all] [--executor local|ray]

Settings come from, in increasing priority: the defaults, ``--config FILE`` (TOML), the
flags. Known errors (bad input, unknown names, invalid settings, missing optional packages,
an unusable ``--out``) print one line on stderr and exit with code 1; no traceback, and
``--out`` is untouched (a run writes into a staging folder and moves the result into place
at the end; ``--overwrite`` replaces an earlier run, ``--resume`` continues an interrupted
one). Exit codes (docs/safety.md): 0 success, 1 error, 2 malformed command line, 3 the run
finished but too few frames got metric depth ("nothing came out"), 130 interrupted (Ctrl-C
or SIGTERM; the partial run is kept for ``--resume``).
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import signal
import sys
import threading
from dataclasses import replace

from matchers import SiftSettings, uses_device
from vio_core.errors import CorruptImageError, MissingDependencyError, SettingsError, VioDepthError
from vio_core.settings import override

from ._version import __version__
from .cli_robot import add_input_flags, add_inspect_parser, add_output_flags, cmd_inspect, input_paths, open_input, \
    sink_factories, written_outputs
from .disparity import DISPARITY_CHOICES, disparity_presets
from .experiments import add_eval_parser, format_results, request_from_args, run_evaluation
from .export import parse_depth_range, parse_ply_spec
from .io import available_formats
from .pipeline import (POINT_SPEC_FORMS, POSE_PRESETS, PRESET_FAMILIES, Pipeline, PipelineSettings,
                       default_matcher_preset, default_points_spec, parse_points_spec)
from .poses import POSE_UNCERTAINTY_PRESETS, GroundTruthPoseSettings
from .report import build_report
from .run import (
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    EXIT_NOTHING_CAME_OUT,
    EXIT_OK,
    OutputFolder,
    OutputFolderError,
    OutputMode,
    RunSettings,
    Terminated,
    dump_config,
    format_table,
    read_config,
    resolve_config,
    raise_terminated,
    run_sequence,
    staging_path,
)
from .run.config import CALIBRATE_POSES_CHOICES
from .run.folder import JOURNAL_NAME
from .run.ranges import check_settings

log = logging.getLogger("vio_depth")


# --------------------------------------------------------------------------- parser
def _add_settings_flags(p: argparse.ArgumentParser) -> None:
    """The flags that shape the settings (shared by ``run`` and ``config``); all default to None."""
    p.add_argument("--config", default=None, metavar="FILE", help="TOML settings file (see `vio-depth config --dump`)")
    g = p.add_argument_group("pipeline")
    g.add_argument("--matcher", default=None,
                   help="matcher preset (see `vio-depth presets`; default: klt with --poses gt or vio, sift "
                        "with the other poses or --guided-matching)")
    g.add_argument("--guided-matching", action="store_true", default=None,
                   help="match each keypoint only inside its epipolar band, widened by the pose's stated "
                        "uncertainty (SIFT; [matcher.guided] in a config file; default off)")
    g.add_argument("--device", default=None, choices=["cpu", "cuda"],
                   help="device of a learned matcher or Depth Anything model (default: cuda when available)")
    g.add_argument("--poses", default=None, help="pose source: gt (sequence poses), imu (gtsam preintegration), "
                                                 "imu_real_mav (imu, accelerometer noise x10 for a real IMU on a "
                                                 "vibrating vehicle), vio (visual-inertial odometry from the "
                                                 "images and the IMU alone, at camera rate; docs/vio.md) or "
                                                 "vio_offline (vio inline with SIFT: 10-20 x slower)")
    g.add_argument("--pairing", default=None,
                   help="pair-selection preset: kitti (5 deg / 1.5 m, default), ddad (5 deg / 2 m), indoor (5 deg / 0.15 m)")
    g.add_argument("--min-rotation", type=float, default=None, metavar="DEG", help="override the rotation threshold")
    g.add_argument("--min-translation", type=float, default=None, metavar="M", help="override the translation threshold")
    g.add_argument("--pose-uncertainty", default=None, metavar="KIND",
                   help="what the sequence's poses get wrong (--poses gt): exact, mocap, kinectfusion, ins, headset "
                        "(default: the sequence's kind; docs/error_model.md)")
    g.add_argument("--max-fit-error", type=float, default=None, metavar="E",
                   help="write a frame only when its predicted relative depth error from the rescaling is at most "
                        "E (default 0.03)")
    g.add_argument("--edge-guard", type=float, default=None, metavar="F",
                   help="do not fit points where the disparity varies by more than the fraction F within 3 px "
                        "(points on depth edges; default: off; 0.1 with --matcher klt, whose corners sit on edges; a "
                        "klt run also pairs no frame below the motion thresholds: docs/benchmarks.md)")
    g.add_argument("--rescaler", default=None, help="rescaler preset: streaming (default), per_frame, paper")
    g.add_argument("--no-temporal", action="store_true", default=None,
                   help="disable the Kalman filter on (alpha, beta)")
    g.add_argument("--points", default=None,
                   help="metric point source: sfm (default; vio with --poses vio), landmarks (a gtsam "
                        "landmark window), vio (the odometry's own landmarks, with --poses vio or vio_offline), or "
                        "lidar:N / random:N sampled from ground truth")
    g.add_argument("--seed", type=int, default=None, help="seed of RANSAC, random reference points and "
                                                          "the SIMULATED disparity (default 0)")
    d = p.add_argument_group("disparity")
    d.add_argument("--disparity", default=None, metavar="SOURCE",
                   help=f"where the disparity comes from: {', '.join(DISPARITY_CHOICES)} (default: sequence, the "
                        "sequence's own; simulated SIMULATES one from ground-truth depth, for datasets without "
                        "Depth Anything predictions)")
    d.add_argument("--disparity-dir", default=None, metavar="DIR",
                   help="read DIR/<image stem>.npy (float32 HxW affine-invariant disparity); implies --disparity files")
    d.add_argument("--model", default=None, metavar="PATH",
                   help="run Depth Anything V1/V2 (transformers folder, .onnx or original .pth); implies --disparity model")
    d.add_argument("--model-variant", default=None,
                   help="for a renamed .pth: vits/vitb/vitl or v1-vitl, v2-vits, ... (see docs/models.md)")
    d.add_argument("--model-input-size", type=int, default=None, metavar="PX",
                   help="Depth Anything input size (default 518)")
    r = p.add_argument_group("run")
    r.add_argument("--max-frames", type=int, default=None, metavar="N",
                   help="process only the first N frames (0, the default: all)")
    r.add_argument("--no-backfill", action="store_true", default=None,
                   help="streaming behaviour only: no backward pass for the first frames that found no "
                        "earlier partner (see docs/design.md)")
    r.add_argument("--calibrate-poses", default=None, choices=list(CALIBRATE_POSES_CHOICES),
                   help="auto (default): with --poses gt, estimate the time offset and camera-to-body transform "
                        "between the sequence's poses and its camera from the images and use the corrected poses "
                        "when significant and well constrained (metrics.json: pose_calibration); off: poses as given")
    r.add_argument("--uncertainty", action="store_true", default=None,
                   help="also write uncertainty/<stem>.png: 1-sigma depth (metres x 256)")
    r.add_argument("--max-depth", type=float, default=None, help="depth cap for evaluation, metres (default 80)")
    r.add_argument("--no-evaluation", action="store_true", default=None,
                   help="do not evaluate against the sequence's ground-truth depth (no dense metrics, oracle or "
                        "point accuracy; faster)")
    o = p.add_argument_group("optional outputs (docs/outputs.md)")
    o.add_argument("--save-npy", action="store_true", default=None,
                   help="also write depth_npy/<stem>.npy: float32 metres, NaN = invalid (exact, no 256 m cap)")
    o.add_argument("--save-preview", action="store_true", default=None,
                   help="also write preview/<stem>.png (colourised depth) and, with ground truth, "
                        "error/<stem>.png (signed relative error)")
    o.add_argument("--preview-range", default=None, metavar="MIN:MAX",
                   help="depth range of the preview colours in metres (default: one range per run)")
    o.add_argument("--preview-colormap", default=None,
                   help="turbo (default), viridis, inferno, magma, plasma, cividis")
    o.add_argument("--save-ply", action="append", default=None, metavar="SPEC",
                   help="point clouds (PLY, world frame): sparse (per-frame points + merged map "
                        "ply/sparse_map.ply), dense[:STRIDE] (back-projected depth, every STRIDE-th pixel, "
                        "default 4); comma-separated or repeated")
    o.add_argument("--ply-frames", default=None, metavar="LIST",
                   help="frames that get dense clouds, e.g. 0,50,100 or 0:130:10 (default: all with depth)")
    o.add_argument("--report", action="store_true", default=None,
                   help="write the run report OUT/report/index.html (+ report.md) at the end; needs matplotlib")


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="vio-depth",
        description="Metric depth maps from affine-invariant disparity and triangulated metric points.",
    )
    p.add_argument("--version", action="version", version=f"vio-depth {__version__}")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-v info, -vv debug)")
    p.add_argument("-q", "--quiet", action="store_true", help="only errors")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="process a sequence and write metric depth maps")
    r.add_argument("sequence", help="sequence folder (native, KITTI raw, 7-Scenes, TUM RGB-D, ASL, DDAD) or ROS bag")
    r.add_argument("--out", required=True, help="output folder (created if missing; never inside an input)")
    mode = r.add_mutually_exclusive_group()
    mode.add_argument("--overwrite", action="store_true",
                      help="replace the run already in --out (atomically, at the end) or discard an interrupted one")
    mode.add_argument("--resume", action="store_true",
                      help="continue the interrupted run of --out from its last complete frame (same settings "
                           "and version; the result equals an uninterrupted run)")
    r.add_argument("--format", default=None, help="sequence format (default: auto-detect)")
    _add_settings_flags(r)
    add_input_flags(r)
    add_output_flags(r)
    r.add_argument("--no-overlap", action="store_true",
                   help="run every stage in one thread, one after the other (same outputs, slower; default: the "
                        "next frames are prepared and the outputs written in worker threads)")
    r.add_argument("--progress", dest="progress", action="store_true", default=None, help="force a progress bar")
    r.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")

    c = sub.add_parser("config", help="print the resolved settings (defaults < --config FILE < flags) as TOML")
    _add_settings_flags(c)
    c.add_argument("--dump", action="store_true", required=True, help="print the complete settings as TOML")

    sub.add_parser("presets", help="list every preset family and name")

    rep = sub.add_parser("report", help="write an HTML + Markdown report of a finished run (also of old runs)")
    rep.add_argument("out_dir", help="the --out folder of a vio-depth run")
    rep.add_argument("--to", default=None, metavar="DIR", help="report folder (default: OUT_DIR/report)")
    add_eval_parser(sub)
    add_inspect_parser(sub)
    return p


# --------------------------------------------------------------------------- settings
#: flags that choose a stage's preset by name (the PipelineSettings field of the same name)
_PRESET_FLAGS = ("matcher", "poses", "pairing", "rescaler")


def settings_from_args(args) -> tuple[PipelineSettings, RunSettings]:
    """Defaults, then the preset flags (``--matcher``, ``--poses``, ``--pairing``, ``--rescaler``),
    then ``--config`` (its stage tables refine those presets; a file naming another preset than
    the flag is refused), then the other flags given on the command line. When neither a flag nor
    the file names a matcher, it follows the pose source (:func:`vio_depth.run.resolve_config`).

    Raises:
        SettingsError / UnknownNameError / InputError: an invalid or inapplicable value.
    """
    chosen = {family: getattr(args, family) for family in _PRESET_FLAGS if getattr(args, family) is not None}
    data = read_config(args.config) if args.config else None
    # guided matching is a SIFT option: it makes sift the matcher when nothing names one
    pipeline, run = resolve_config(chosen, data, source=args.config,
                                   default_matcher="sift" if args.guided_matching else None)
    s = pipeline
    if args.guided_matching:
        if not isinstance(s.matcher, SiftSettings):
            raise SettingsError(f"--guided-matching needs a nearest-neighbour matcher (sift); the "
                                f"{type(s.matcher).__name__} matcher matches by itself")
        s = override(s, {"matcher": {"guided": {"enabled": True}}})
    if args.min_rotation is not None or args.min_translation is not None:
        s = replace(s, pairing=override(s.pairing, {k: v for k, v in (("min_rotation_deg", args.min_rotation),
                                                                      ("min_translation_m", args.min_translation))
                                                    if v is not None}, where="pairing"))
    if args.max_fit_error is not None:
        s = override(s, {"rescaler": {"max_fit_error": args.max_fit_error}})
    if args.edge_guard is not None:
        s = override(s, {"rescaler": {"max_disparity_spread": args.edge_guard}})
    if args.pose_uncertainty is not None:
        if not isinstance(s.poses, GroundTruthPoseSettings):
            raise SettingsError("--pose-uncertainty states the error of the sequence's poses (--poses gt); the "
                                "imu and vio sources state their own covariance")
        s = replace(s, poses=replace(s.poses, uncertainty=POSE_UNCERTAINTY_PRESETS[args.pose_uncertainty]))
    if args.no_temporal:
        s = replace(s, rescaler=replace(s.rescaler, temporal=None))
    if args.points is not None:
        s = replace(s, points=parse_points_spec(args.points, seed=s.points.seed))
    if args.seed is not None:
        s = override(s, {"rescaler": {"ransac": {"seed": args.seed}}, "disparity": {"seed": args.seed}})
        s = replace(s, points=override(s.points, seed=args.seed, where="points"))
    s = _disparity_from_args(args, s)
    if args.device is not None:
        applied = False
        if uses_device(s.matcher):
            s = replace(s, matcher=override(s.matcher, device=args.device, where="matcher"))
            applied = True
        if s.disparity.source == "model":
            s = override(s, {"disparity": {"model": {"device": args.device}}})
            applied = True
        if not applied:
            raise SettingsError(f"--device {args.device} does not apply: the {type(s.matcher).__name__} matcher "
                                "and this disparity source run on the CPU")
    run = override(run, {k: v for k, v in (("max_frames", args.max_frames), ("uncertainty", args.uncertainty),
                                            ("max_eval_depth", args.max_depth),
                                            ("calibrate_poses", args.calibrate_poses)) if v is not None}, where="run")
    if args.no_backfill:
        run = replace(run, backfill=False)
    if args.no_evaluation:
        run = replace(run, evaluate=False)
    run = _exports_from_args(args, run)
    check_settings(s, run)  # every numeric setting within its documented range (vio_depth/run/ranges.py)
    return s, run


def _exports_from_args(args, run: RunSettings) -> RunSettings:
    """The optional-output flags applied to ``run.export`` (and ``run.report``)."""
    export = run.export
    style = export.style
    if args.preview_colormap is not None or args.preview_range is not None:
        style = override(style, {k: v for k, v in (("colormap", args.preview_colormap),
                                                   ("depth_range", None if args.preview_range is None
                                                    else parse_depth_range(args.preview_range))) if v is not None},
                         where="preview")
        export = replace(export, preview_style=style, preview=style if export.preview is not None else None)
    if args.save_preview:
        export = replace(export, preview=style)
    if args.save_npy:
        export = replace(export, npy=True)
    if args.save_ply or args.ply_frames is not None:
        export = replace(export, ply=parse_ply_spec(args.save_ply or [], frames=args.ply_frames))
    run = replace(run, export=export)
    if args.report:
        run = replace(run, report=True)
    if run.report and importlib.util.find_spec("matplotlib") is None:
        raise MissingDependencyError("matplotlib", "report", "the run report (--report)")
    return run


def _disparity_from_args(args, s: PipelineSettings) -> PipelineSettings:
    if args.disparity_dir and args.model:
        raise SettingsError("--disparity-dir and --model are mutually exclusive")
    source = args.disparity
    if source is not None and source.lower() not in DISPARITY_CHOICES:
        hint = " (a folder of <stem>.npy files goes to --disparity-dir)" if "/" in source or "." in source else ""
        raise SettingsError(f"--disparity {source!r}: expected one of {', '.join(DISPARITY_CHOICES)}{hint}")
    implied = "files" if args.disparity_dir else "model" if args.model else None
    if source is not None and implied is not None and source.lower() != implied:
        raise SettingsError(f"--disparity {source} contradicts --{'disparity-dir' if implied == 'files' else 'model'}")
    changes: dict = {}
    if source is not None or implied is not None:
        changes["source"] = (source or implied).lower()
        changes["path"] = args.disparity_dir or args.model or ""
    if args.model_variant is not None:
        changes["model_variant"] = args.model_variant
    if args.model_input_size is not None:
        changes["model"] = {"input_size": args.model_input_size}
    return override(s, {"disparity": changes}) if changes else s


# --------------------------------------------------------------------------- commands
def _default_marks(family: str, presets) -> dict[str, str]:
    """Preset name -> the mark ``vio-depth presets`` prints after it: ``(default)``, or for the
    matcher, which follows the pose source, the pose presets it is the default with."""
    if family != "matcher":
        return {presets.default: " (default)"}
    with_poses: dict[str, list[str]] = {}
    for pose in POSE_PRESETS:
        with_poses.setdefault(default_matcher_preset(POSE_PRESETS[pose]), []).append(pose)
    return {name: f" (default with --poses {', '.join(poses)})" for name, poses in with_poses.items()}


def _cmd_presets() -> int:
    for family, presets in PRESET_FAMILIES.items():
        print(f"{family}:")
        marks = _default_marks(family, presets)
        for name in presets:
            print(f"  {name:20s} {presets.describe(name)}{marks.get(name, '')}")
    print("pose uncertainty (--pose-uncertainty; default: the sequence's kind of poses):")
    for name in POSE_UNCERTAINTY_PRESETS:
        print(f"  {name:20s} {POSE_UNCERTAINTY_PRESETS.describe(name)}")
    with_poses = [p for p in POSE_PRESETS if default_points_spec(POSE_PRESETS[p]) != "sfm"]
    print("points:\n  " + ", ".join(POINT_SPEC_FORMS) + "   (default: sfm; vio with --poses "
          + ", ".join(with_poses) + ")")
    print("disparity:\n  " + ", ".join(DISPARITY_CHOICES) + "   (simulation presets: " + ", ".join(disparity_presets()) + ")")
    print("formats:\n  " + ", ".join(available_formats()))
    return 0


def _cmd_config(args) -> int:
    pipeline, run = settings_from_args(args)
    print(dump_config(pipeline, run), end="")
    return 0


def _run_inputs(args, settings: PipelineSettings) -> list:
    """The paths a run reads besides the sequence folder (``--out`` may not touch them)."""
    return [p for p in (settings.disparity.path, args.config) if p] + input_paths(args)


def _cmd_run(args) -> int:
    # Names, numbers and the output folder first: a typo fails before any file is read or written.
    settings, run = settings_from_args(args)
    mode = OutputMode.RESUME if args.resume else OutputMode.OVERWRITE if args.overwrite else OutputMode.NEW
    inputs = _run_inputs(args, settings)
    OutputFolder(args.out, mode, inputs=[args.sequence, *inputs]).check_mode()
    sinks = sink_factories(args)
    sequence = open_input(args)
    pipeline = Pipeline(settings, sequence=sequence)
    # Check the first frame's inputs before anything is written.
    first = sequence[0]
    try:
        first.image()
    except CorruptImageError:
        pass  # damaged pixels are the frame's status (corrupt_image), not an error
    if settings.disparity.source == "files" and pipeline.disparity_source(first) is None:
        raise SettingsError(f"{pipeline.disparity_source.path_for(first)}: missing "
                            "(expected one <image stem>.npy per frame)")
    try:
        summary = run_sequence(sequence, pipeline, args.out, run, progress=args.progress, command=args.command_line,
                               mode=mode, inputs=inputs, overlap=not args.no_overlap, sinks=sinks)
    except (VioDepthError, OSError, KeyboardInterrupt) as exc:
        staging = staging_path(args.out)
        if (staging / JOURNAL_NAME).is_file() and not isinstance(exc, OutputFolderError):
            exc.vio_depth_note = f"; the partial run is kept in {staging} (--resume continues it)"
        raise
    finally:
        pipeline.close()  # its worker processes, if any
    if summary.resumed_frames == -1:
        print(f"{args.out}: already holds this finished run; nothing to resume")
    print(format_table(summary))
    print("\n".join(written_outputs(args)), end="\n" if written_outputs(args) else "")
    verdict = summary.verdict
    if verdict and not verdict.get("ok", True):
        print(f"vio-depth: {verdict['message']}", file=sys.stderr)
        return EXIT_NOTHING_CAME_OUT
    return EXIT_OK


def _cmd_report(args) -> int:
    result = build_report(args.out_dir, report_dir=args.to)
    print(f"report: {result.html} (and {result.markdown.name})")
    for note in result.omitted:
        print(f"  {note}")
    return 0


def _cmd_eval(args) -> int:
    outcome = run_evaluation(request_from_args(args))
    print(format_results(outcome.rows))
    print(f"{outcome.tasks} tasks ({outcome.tasks_cached} from the cache) in {outcome.wall_seconds:.0f} s; "
          f"wrote {outcome.out / 'results.csv'} and " + ", ".join(str(d) for d in outcome.documents))
    if any(r.get("disparity") == "simulated" for r in outcome.rows):
        print("note: SIMULATED disparity in this evaluation (not Depth Anything predictions)")
    return 0


def _configure_logging(verbose: int, quiet: bool) -> None:
    """Log records of the ``vio_depth`` logger go to stderr: warnings by default, -v info,
    -vv debug, -q errors only (one handler, also when ``main`` is called repeatedly)."""
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    for h in [h for h in log.handlers if getattr(h, "_vio_depth_cli", False)]:
        log.removeHandler(h)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("vio-depth: %(levelname)s: %(name)s: %(message)s"))
    handler._vio_depth_cli = True
    log.addHandler(handler)
    log.setLevel(level)


def _safe_streams() -> None:
    """Paths with bytes that are not UTF-8 reach messages as surrogates: print them escaped."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.reconfigure(errors="backslashreplace")
        except (AttributeError, ValueError, OSError):
            pass


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    _safe_streams()
    args = _build_parser().parse_args(argv)
    args.command_line = ["vio-depth", *argv]
    _configure_logging(args.verbose, args.quiet)
    previous = None
    if threading.current_thread() is threading.main_thread():  # signals reach the main thread only
        previous = signal.signal(signal.SIGTERM, raise_terminated)
    try:
        return _main(args)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _main(args) -> int:
    """The command of ``args``; known errors become one line and an exit code (docs/safety.md)."""
    try:
        if args.command == "presets":
            return _cmd_presets()
        if args.command == "config":
            return _cmd_config(args)
        if args.command == "report":
            return _cmd_report(args)
        if args.command == "eval":
            return _cmd_eval(args)
        if args.command == "inspect":
            return cmd_inspect(args)
        return _cmd_run(args)
    except VioDepthError as exc:
        print(f"vio-depth: error: {_one_line(exc)}{getattr(exc, 'vio_depth_note', '')}", file=sys.stderr)
        return EXIT_ERROR
    except OSError as exc:  # the environment (disk full, a vanished folder): one line, never a traceback
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"vio-depth: error: {where}{exc.strerror or exc}{getattr(exc, 'vio_depth_note', '')}",
              file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (Terminated): the same exit, resumable
        how = " (SIGTERM)" if isinstance(exc, Terminated) else ""
        print(f"vio-depth: interrupted{how}{getattr(exc, 'vio_depth_note', '')}", file=sys.stderr)
        return EXIT_INTERRUPTED


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split("\n"))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
