"""``vio-depth report OUT_DIR``: an HTML page and a Markdown twin with plots about a finished run.

Reads only the run's own files (:mod:`.load`), so it works on old output folders too;
plots need matplotlib (the ``report`` extra), imported only when a plot is made.
"""

from .build import ReportResult, build_report, status_runs
from .load import RunData, load_run
from .plots import FIGURES, figure_dense_error, figure_point_accuracy, figure_points, figure_scale, figure_status
from .render import Code, Image, Note, Section, Strip, Table, Text, to_html, to_markdown

__all__ = [
    "Code", "FIGURES", "Image", "Note", "ReportResult", "RunData", "Section", "Strip", "Table", "Text",
    "build_report", "figure_dense_error", "figure_point_accuracy", "figure_points", "figure_scale",
    "figure_status", "load_run", "status_runs", "to_html", "to_markdown",
]
