"""Saying when nothing came out: the verdict on a finished run, and the CLI's exit codes.

A run can finish without an error and still give (almost) no metric depth: a one-frame
sequence, a static camera, a pure rotation, an all-zero or all-NaN disparity. Such a run
is written as usual (``frames.jsonl`` says per frame why), but it is not a success: when
fewer than ``RunSettings.min_depth_fraction`` (default :data:`MIN_DEPTH_FRACTION`, 0.5) of
the processed frames got metric depth, :func:`judge_run` returns a verdict that is not
ok, naming the dominant status among the frames without depth and one of its reasons,
and ``vio-depth run`` prints it as one line on stderr and exits with
:data:`EXIT_NOTHING_CAME_OUT`.

Why 0.5: every healthy run measured so far gives depth for 96-100 % of its frames (street
and room samples with gt and imu poses, 7-Scenes frames 0-119, KITTI-tiny; docs/safety.md),
and every failure case of issue 12 gives 0 %; half is far from both.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import asdict, dataclass

#: default least fraction of processed frames with metric depth for a run to count as a success
MIN_DEPTH_FRACTION = 0.5

#: exit codes of ``vio-depth`` (docs/safety.md)
EXIT_OK = 0
EXIT_ERROR = 1  # bad input, settings or output folder: one line on stderr, --out untouched
EXIT_USAGE = 2  # the command line itself is malformed (argparse)
EXIT_NOTHING_CAME_OUT = 3  # the run finished and was written, but too few frames got metric depth
EXIT_INTERRUPTED = 130  # Ctrl-C; the partial run is kept for --resume

#: statuses with metric depth (:class:`~vio_depth.pipeline.FrameStatus`)
_WITH_DEPTH = frozenset({"ok", "fallback_scale_only", "fallback_previous_fit"})


@dataclass(frozen=True)
class RunVerdict:
    """Whether a run gave enough metric depth.

    Attributes:
        ok: at least ``min_fraction`` of the processed frames have metric depth (and at least one).
        frames_with_depth / frames_processed: counts.
        min_fraction: the bound used.
        dominant_status: the most frequent status among the frames without depth ("" if none).
        message: one line for people ("" when ok).
    """

    ok: bool
    frames_with_depth: int
    frames_processed: int
    min_fraction: float
    dominant_status: str = ""
    message: str = ""

    @property
    def exit_code(self) -> int:
        return EXIT_OK if self.ok else EXIT_NOTHING_CAME_OUT

    def to_json(self) -> dict:
        return asdict(self)


def judge_run(summary, records: list[dict], min_fraction: float = MIN_DEPTH_FRACTION) -> RunVerdict:
    """The verdict on a finished run.

    Args:
        summary: the run's :class:`~vio_depth.run.summary.RunSummary` (frame counts).
        records: the frame records (JSON form) in frame order.
        min_fraction: least fraction of processed frames with metric depth.
    """
    n = int(summary.frames_processed)
    k = int(summary.frames_with_depth)
    ok = n > 0 and k > 0 and k >= min_fraction * n
    without = [r for r in records if r.get("status") not in _WITH_DEPTH]
    dominant, message = "", ""
    if without:
        dominant, count = Counter(r.get("status", "") for r in without).most_common(1)[0]
    if not ok:
        if n == 0:
            message = "no frame was processed"
        else:
            what = "no metric depth for any" if k == 0 else f"metric depth for only {k}"
            message = (f"{what} of {n} processed frame(s) (less than {min_fraction:.0%}); "
                       f"dominant status {dominant} ({count} frame(s))")
            # the latest such frame's reason: the first frame's "no keyframe yet" says least
            example = next((r.get("reason", "") for r in reversed(without) if r.get("status") == dominant), "")
            if example:
                message += f": {_one_line(example)}"
    return RunVerdict(ok, k, n, float(min_fraction), dominant, message)


def _one_line(text: str, limit: int = 160) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."
