"""The ``vio-depth eval`` command-line arguments and their translation into an :class:`~.command.EvalRequest`."""

from __future__ import annotations

import argparse
from pathlib import Path

from vio_core.errors import SettingsError

from ..evaluation import STUDIES
from .command import EvalRequest, parse_studies
from .plan import DISPARITY_OPTIONS, PROFILES, FrameSelection, SequenceEntry, entries_from_split, parse_sequence_arg
from .tasks import EXECUTORS, ExecutorSettings
from .variants import parse_variants, variant_groups

EPILOG = """\
sequence options (after @, comma-separated): outdoor | indoor | ddad (profile), frames=A:B[:S],
disparity=sequence|simulated, max-depth=M, crop=none|garg|eigen, pairing=P, paper=P, format=F, name=N
e.g. ../shared/data/7scenes_redkitchen@indoor,disparity=simulated,frames=0:120

variants: oracle, lidar:N, sfm[:MATCHER][:POSES], sfm-no-ransac[:MATCHER][:POSES], fixed, paper-reference;
groups: paper = {paper}; all = paper + sfm with every learned matcher and with IMU poses
studies: {studies}
docs/evaluation.md shows a complete run; docs/evaluation_cluster.md runs it on a Ray cluster.
"""


def add_eval_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``eval`` sub-command to ``subparsers`` (of the ``vio-depth`` parser)."""
    e = subparsers.add_parser(
        "eval", help="evaluate variants over many sequences (tables, robustness studies; local pool or Ray)",
        epilog=EPILOG.format(paper=", ".join(variant_groups()["paper"]), studies=", ".join(STUDIES)),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    e.add_argument("sequences", nargs="*", metavar="SEQ[@OPTIONS]", help="sequence folders, with options after @")
    e.add_argument("--out", required=True, help="evaluation folder: results.csv, frames.csv, studies/, report.md, "
                                                "cache/ (an interrupted evaluation resumes from it)")
    e.add_argument("--variants", default="paper", help="comma-separated variants or groups (default: paper)")
    e.add_argument("--studies", default="none", help="robustness studies: all, none (default) or a list")
    e.add_argument("--study-frames", type=int, default=20, metavar="N",
                   help="studies score a block of N evaluated frames in the middle of each sequence "
                        "(default 20)")
    d = e.add_argument_group("defaults of every sequence (its @options override them)")
    d.add_argument("--profile", default="outdoor", choices=list(PROFILES))
    d.add_argument("--disparity", default="sequence", choices=list(DISPARITY_OPTIONS),
                   help="sequence: the sequence's own maps; simulated: SIMULATED from ground-truth depth")
    d.add_argument("--frames", default=None, metavar="A:B[:S]", help="frames processed (and every S-th evaluated)")
    d.add_argument("--max-depth", type=float, default=None, metavar="M", help="depth cap in metres")
    d.add_argument("--crop", default=None, help="none, garg or eigen (default: garg for KITTI raw outdoors)")
    d.add_argument("--pairing", default=None, help="pairing preset of our pipeline (default: the profile's)")
    d.add_argument("--kitti-split", default=None, metavar="FILE",
                   help="KITTI split file (Eigen test files): evaluate exactly its frames, one sequence per drive")
    d.add_argument("--kitti-root", default=None, metavar="DIR", help="KITTI raw root of --kitti-split")
    x = e.add_argument_group("execution")
    x.add_argument("--executor", default="local", choices=list(EXECUTORS),
                   help="local: process pool over all cores (default); sequential; ray")
    x.add_argument("--workers", type=int, default=None, metavar="N",
                   help="processes of the local pool / CPUs of a local Ray instance (default: all cores)")
    x.add_argument("--address", default=None,
                   help="Ray: join this running cluster ('auto', 'ray://head:10001') instead of starting one")
    x.add_argument("--seed", type=int, default=0, help="seed of RANSAC, SIMULATED disparity and perturbations")
    x.add_argument("--markdown", default=None, metavar="FILE.md",
                   help="also write this document, its figures in FILE/ beside it (e.g. docs/evaluation.md)")
    x.add_argument("--compare-with", default=None, metavar="DIR",
                   help="an evaluation folder of the same command run elsewhere (e.g. on Ray): its wall time and "
                        "whether every number agrees go into the documents")
    x.add_argument("--progress", dest="progress", action="store_true", default=None, help="force a progress bar")
    x.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    return e


def request_from_args(args) -> EvalRequest:
    """The :class:`EvalRequest` of parsed ``vio-depth eval`` arguments.

    Raises:
        SettingsError / UnknownNameError / InputError: an invalid option or sequence.
    """
    defaults = SequenceEntry(path="", profile=args.profile, disparity=args.disparity,
                             frames=FrameSelection.parse(args.frames) if args.frames else FrameSelection(),
                             max_depth=args.max_depth, crop=args.crop, pairing=args.pairing)
    entries = [parse_sequence_arg(s, defaults) for s in args.sequences]
    if (args.kitti_split is None) != (args.kitti_root is None):
        raise SettingsError("--kitti-split and --kitti-root go together")
    if args.kitti_split is not None:
        entries += entries_from_split(args.kitti_split, args.kitti_root, defaults)
    if args.compare_with is not None and not (Path(args.compare_with) / "eval.json").is_file():
        raise SettingsError(f"--compare-with {args.compare_with}: not an evaluation folder (no eval.json)")
    executor = ExecutorSettings(kind=args.executor, workers=args.workers, address=args.address)
    return EvalRequest(
        entries=entries, variants=parse_variants(args.variants), out=Path(args.out),
        studies=parse_studies(args.studies), study_frames=args.study_frames, executor=executor, seed=args.seed,
        markdown=None if args.markdown is None else Path(args.markdown),
        compare_with=None if args.compare_with is None else Path(args.compare_with),
        command=list(getattr(args, "command_line", [])), progress=args.progress)
