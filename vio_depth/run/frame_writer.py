"""What a run does with each processed frame: its files, exports, evaluation, record and journal line.

:class:`FrameWriter` holds the per-frame outputs of a run. :meth:`FrameWriter.job` turns a
frame's :class:`~vio_depth.pipeline.FrameResult` into the job the run's
:class:`~vio_depth.run.overlap.OrderedWriter` executes, in frame order:

1. the depth files (:class:`~vio_depth.run.outputs.RunOutputs`), the optional exports
   (:class:`~vio_depth.export.RunExporter`) and every :class:`~vio_depth.run.sinks.FrameSink`,
   all given the frame as :class:`~vio_depth.run.output_poses.OutputPoses` presents it (the
   run's own pose, never one the run did not use);
2. the evaluation against ground-truth depth, when the sequence has it;
3. the frame's record: appended to the journal, or, for a frame replayed by a resumed run,
   compared with the journaled one (:func:`~vio_depth.run.resume.check_replayed`);
4. what the run keeps of the frame until its end (:mod:`vio_depth.run.kept`).
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from typing import Callable

from ..evaluation import FrameEvaluation, evaluate_frame
from ..export import RunExporter
from ..frame import Frame
from ..io import Sequence
from ..pipeline import FrameResult, Pipeline
from .config import RunSettings
from .folder import OutputFolder
from .kept import KeptFrame, pack_record, slim_evaluation, unpack_record
from .output_poses import OutputPoses
from .outputs import RunOutputs
from .record import FrameRecord, frame_record
from .resume import ResumePlan, check_replayed
from .sinks import FrameSink


class FrameWriter:
    """The per-frame outputs of one run, written into ``folder.staging``.

    Args:
        sequence: the run's sequence. pipeline: its pipeline. folder: its output folder.
        settings: :class:`RunSettings`. plan: where the run starts (frames to replay).
        n: the frames the run processes. sinks: the further consumers of every frame.

    Attributes:
        outputs: the depth files and the run-end ``frames.jsonl`` / ``trajectory.tum`` / ``metrics.json``.
        exporter: the optional exports (``--save-*``, the report's thumbnails), or None.
        results: frame index -> its :class:`FrameResult` until written, then its :class:`KeptFrame`.
    """

    def __init__(self, sequence: Sequence, pipeline: Pipeline, folder: OutputFolder, settings: RunSettings,
                 plan: ResumePlan, n: int, sinks: list[FrameSink] = ()):
        out_dir = folder.staging
        self.folder = folder
        self.plan = plan
        self.sinks = sinks
        self.outputs = RunOutputs(out_dir, uncertainty=settings.uncertainty)
        export = settings.export if not settings.report else replace(settings.export, thumbnails=True)
        self.exporter = RunExporter(out_dir, export) if export.any else None
        self.evaluate = settings.evaluate and sequence.has_gt_depth
        self.evaluate_points = not pipeline.settings.points.uses_ground_truth  # reference points come from the GT
        self.settings = settings
        self.poses = OutputPoses(sequence, pipeline, n)  # the outputs see the run's own poses only
        # every frame until the run's end, in a few hundred bytes each (run/kept.py): flat memory
        self.results: dict[int, FrameResult | KeptFrame] = {}
        self._done: dict[int, tuple[bytes, FrameEvaluation | None]] = {}

    def _finish_frame(self, frame: Frame, res: FrameResult, write: bool) -> tuple[FrameRecord, FrameEvaluation | None]:
        """Frame ``frame``'s files (``write``), exports, sinks and evaluation; returns its record."""
        t = time.perf_counter()
        if write:
            self.outputs.write_frame(res)
        if self.exporter is not None:
            self.exporter.add_frame(frame, res, write=write)
        for sink in self.sinks:  # replayed frames too: a sink's file is written anew by a resumed run
            sink.add_frame(frame, res)
        res.timings["write"] = time.perf_counter() - t
        evaluation = None
        if self.evaluate:
            t = time.perf_counter()
            gt = frame.gt_depth()
            if gt is not None:
                s = self.settings
                evaluation = evaluate_frame(gt, res.depth, res.disparity, res.points_uv, res.points_depth,
                                            min_depth=s.min_eval_depth, max_depth=s.max_eval_depth,
                                            points=self.evaluate_points)
            res.timings["evaluation"] = time.perf_counter() - t
        return frame_record(res, evaluation), evaluation

    def job(self, i: int, frame: Frame, res: FrameResult, journal: bool = True) -> Callable[[], None]:
        """The writer's job for frame ``i``: its files, evaluation and record, then its journal
        line. ``journal=False``: a frame of the backward pass (already journaled once). Call in
        the order the run writes its frames (:class:`OutputPoses` chains poses on earlier frames)."""
        replay = i < self.plan.start and journal
        frame = self.poses.output_frame(frame, res)

        def job() -> None:
            record, evaluation = self._finish_frame(frame, res, write=not replay)
            record = record.to_json()
            if replay:
                check_replayed(self.folder, self.plan, i, frame.stem, record)
            elif journal:
                self.folder.append(record)
            self._done[i] = pack_record(record), slim_evaluation(evaluation)
            self.results[i] = KeptFrame.of(res)
        return job

    def record_json(self, i: int) -> str:
        """Frame ``i``'s record, as its ``frames.jsonl`` line (once its job has run)."""
        return unpack_record(self._done[i][0])

    def record(self, i: int) -> dict:
        """Frame ``i``'s record (once its job has run)."""
        return json.loads(self.record_json(i))

    def evaluation(self, i: int) -> FrameEvaluation | None:
        """Frame ``i``'s evaluation without its per-point arrays, or None (once its job has run)."""
        return self._done[i][1]
