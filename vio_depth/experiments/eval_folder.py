"""The ``vio-depth eval --out`` folder: the same refusals as ``vio-depth run --out`` (issue 23).

An evaluation writes into its folder directly (its task cache makes an interrupted
evaluation resumable, so there is no staging folder to swap), which makes the checks before
the first write all the more important. Refused with one line, nothing written:

* everything :func:`vio_depth.run.folder.check_out_path` refuses: ``--out`` equal to,
  inside or containing an input (every sequence folder, the KITTI split file and root,
  ``--compare-with``), a file, a symbolic link to nothing, under ``/proc``, ``/sys`` or
  ``/dev``, too long a name (``vio-depth eval SEQ --out SEQ`` wrote 19 files into the
  sequence folder);
* ``--markdown`` inside an input;
* a non-empty folder without vio-depth's evaluation marker (``vio-depth-eval.json``,
  :mod:`vio_depth.io.marker`): a user's folder, or a run folder;
* a folder another evaluation is writing (``flock`` on the folder while it works).

A folder that carries the marker is continued: finished tasks come from its cache, the
result files are rewritten.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path
from typing import Iterable

from ..run.folder import OutputFolderError, check_out_path
from ..io.marker import EVAL_MARKER, read_marker, write_marker


def _inside(child: Path, parent: Path) -> bool:
    return child == parent or parent in child.parents


class EvalFolder:
    """The ``--out`` folder of one evaluation.

    Args:
        out: the evaluation folder.
        inputs: paths the evaluation reads; ``out`` may not be, lie in or contain any of them.
        markdown: the extra Markdown document to write, or None; it may not lie in an input.

    Usage: :meth:`claim` (checks, creates, marks and locks the folder), then write into
    :attr:`out`; :meth:`release` at the end (also after a failure).
    """

    def __init__(self, out, inputs: Iterable = (), markdown=None):
        inputs = [p for p in inputs if p is not None and str(p) != ""]
        self.out = check_out_path(out, inputs)
        if markdown is not None:
            doc = Path(os.path.realpath(markdown))
            for given in inputs:
                if _inside(doc, Path(os.path.realpath(given))):
                    raise OutputFolderError(f"--markdown {markdown}: lies inside the input {given}; vio-depth never "
                                            "writes into its inputs")
        self._fd: int | None = None

    def claim(self) -> None:
        """Refuse a non-empty folder without the evaluation marker or one another evaluation
        holds; else create it, write the marker (first) and lock it.

        Raises:
            OutputFolderError: see the module docstring (before anything is written).
        """
        try:
            entries = os.listdir(self.out)
        except FileNotFoundError:
            entries = []
        except OSError as exc:
            raise OutputFolderError(f"{self.out}: cannot read the evaluation folder ({exc.strerror})") from None
        marked = read_marker(self.out, "eval") is not None
        if entries and not marked:
            what = "a vio-depth run folder" if read_marker(self.out, "run") is not None else "no vio-depth evaluation"
            raise OutputFolderError(
                f"{self.out}: not empty ({len(entries)} entries) and holds {what} (no {EVAL_MARKER} marker); "
                "vio-depth writes evaluations only into an empty or new folder or one of its own evaluations "
                "(choose another --out)")
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.out, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
        except OSError as exc:
            raise OutputFolderError(f"{self.out}: cannot create the evaluation folder ({exc.strerror})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise OutputFolderError(f"{self.out}: another vio-depth eval is writing it right now; wait for it to "
                                    "finish") from None
        self._fd = fd
        if not marked:
            try:
                write_marker(self.out, "eval")
            except OSError as exc:
                self.release()
                raise OutputFolderError(f"{self.out}: cannot write into the evaluation folder ({exc.strerror})") \
                    from None

    def release(self) -> None:
        """Unlock the folder."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


__all__ = ["EvalFolder"]
