"""``vio-depth eval``: the paper's protocol over many sequences and variants, on one machine or Ray.

=================  ===========================================================================
module             job
=================  ===========================================================================
``variants``       :class:`Variant`, :func:`parse_variants`: oracle, lidar:N, sfm, sfm-no-ransac,
                   fixed, paper-reference
``plan``           :class:`SequenceEntry` (``SEQ@options``), profiles, frames, KITTI split files
``context``        a task's opened inputs: :class:`FrameRange`, the cached disparity, the mask
``fits``           least squares (per frame, pooled) and the three fits the studies compare
``scores``         :class:`FrameScore` per frame, :func:`aggregate` into a results row
``runner``         :func:`run_variant_task`: one variant on one sequence
``studies``        :func:`run_study_task`: one robustness study on one sequence
``results``        the CSV / JSON files, :func:`compare_evaluations`
``figures``        the PNGs (matplotlib, lazily)
``document``       :func:`write_document`: the Markdown report of an evaluation folder
``command``        :func:`run_evaluation` (:class:`EvalRequest`): tasks, executors, outputs
``tasks``          :func:`run_tasks`: tasks sequentially, on a process pool or on Ray, cached
``arguments``      the command-line options of ``vio-depth eval``
=================  ===========================================================================

Python::

    from vio_depth.experiments import EvalRequest, parse_sequence_arg, parse_variants, run_evaluation

    outcome = run_evaluation(EvalRequest(
        entries=[parse_sequence_arg("sample_sequences/street@frames=0:60"),
                 parse_sequence_arg("sample_sequences/room@indoor,frames=0:60")],
        variants=parse_variants("oracle,sfm,paper-reference"), out=Path("out/eval")))
"""

from .arguments import add_eval_parser, request_from_args
from .command import EvalOutcome, EvalRequest, build_tasks, format_results, parse_studies, run_eval_task, run_evaluation
from .context import FrameRange, TaskContext, open_task
from .document import write_document
from .fits import FIT_METHODS, LinearFit, PooledSums, fit_and_depth, least_squares_fit
from .plan import (
    PROFILES,
    FrameSelection,
    ResolvedEntry,
    SequenceEntry,
    entries_from_split,
    parse_sequence_arg,
    resolve_entry,
)
from .results import Comparison, compare_evaluations
from .runner import evaluate_variant, pipeline_settings, run_variant_task, variant_pipeline
from .scores import FrameScore, aggregate
from .studies import run_study, run_study_task
from .tasks import EXECUTORS, ExecutorSettings, Task, TaskCache, TaskError, execute_task, package_version, run_tasks
from .variants import Variant, VariantKind, parse_variant, parse_variants, variant_groups

__all__ = [
    "EXECUTORS",
    "FIT_METHODS",
    "PROFILES",
    "Comparison",
    "EvalOutcome",
    "EvalRequest",
    "ExecutorSettings",
    "FrameRange",
    "FrameScore",
    "FrameSelection",
    "LinearFit",
    "PooledSums",
    "ResolvedEntry",
    "SequenceEntry",
    "Task",
    "TaskCache",
    "TaskContext",
    "TaskError",
    "Variant",
    "VariantKind",
    "add_eval_parser",
    "aggregate",
    "build_tasks",
    "compare_evaluations",
    "entries_from_split",
    "evaluate_variant",
    "execute_task",
    "fit_and_depth",
    "format_results",
    "least_squares_fit",
    "open_task",
    "package_version",
    "parse_sequence_arg",
    "parse_studies",
    "parse_variant",
    "parse_variants",
    "pipeline_settings",
    "request_from_args",
    "resolve_entry",
    "run_eval_task",
    "run_evaluation",
    "run_study",
    "run_study_task",
    "run_tasks",
    "run_variant_task",
    "variant_pipeline",
    "variant_groups",
    "write_document",
]
