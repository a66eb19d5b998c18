"""Output folders that cannot hurt: path checks, a staging folder, an atomic swap into place.

A run never writes into ``--out`` directly. It writes into a **staging folder** next to it
(``.<name>.vio-depth-partial``, same parent, so the final move is a rename on one file
system) and moves the complete result into place only at the end:

* ``--out`` missing: the staging folder is renamed to it.
* ``--out`` an empty folder, or a finished vio-depth run replaced with ``--overwrite``: the
  two folders are swapped atomically (Linux ``renameat2(RENAME_EXCHANGE)``; elsewhere two
  renames) and the old one is deleted. At every instant ``--out`` holds either the old
  complete result or the new one.

Refused before anything is written (:func:`check_out_path`, :meth:`OutputFolder.claim`):
``--out`` that is a file, equal to / inside / containing an input (the sequence folder,
``--disparity-dir``, ``--model``, ``--config``) or whose staging folder would be one, under
``/proc``, ``/sys`` or ``/dev``, too long a name, or a symbolic link to nothing; a non-empty
``--out`` holding a vio-depth run unless ``--overwrite`` or ``--resume``; a non-empty
``--out`` that holds no vio-depth run, always (vio-depth never replaces a folder it did not
write); a staging folder locked by a live run.

**What vio-depth may delete** (issue 23): only folders that carry its marker
(:mod:`vio_depth.io.marker`, ``vio-depth-run.json``, written first into every staging
folder): the old content of ``--out`` after the swap (its marker must still carry the id
read when the run started), a staging folder discarded with ``--overwrite`` or left over
from a finished swap, and the per-frame files a resume prunes inside its own staging
folder. A folder with the staging name but no marker is refused, never deleted (an input
folder named ``.out.vio-depth-partial`` was deleted as a "leftover staging folder").

**A symbolic link as ``--out``** is followed: the staging folder is made next to the
link's target and the result replaces the target's content; the link stays. A link to
nothing is refused (the run used to replace the link itself with a folder).

While a run works, its staging folder holds the **journal** (``journal.jsonl``: the run
header, then one frame record per completed frame, appended after that frame's files are
written) and is locked (``flock`` on the folder). A failed, interrupted or killed run
leaves the staging folder; ``--resume`` continues it (:mod:`vio_depth.run.resume`),
``--overwrite`` discards it. The journal is removed before the swap, so a finished
``--out`` never holds one.
"""

from __future__ import annotations

import enum
import errno
import fcntl
import hashlib
import json
import logging
import os
import shutil
from pathlib import Path
from typing import Iterable

from vio_core.errors import InputError

from ..io.depth_png import write_bytes_atomic
from ..io.marker import RUN_MARKER, read_marker, write_marker
from .swap import aside_path, replace_folder

log = logging.getLogger(__name__)

#: suffix of the staging folder next to ``--out``
STAGING_SUFFIX = ".vio-depth-partial"
#: the journal inside the staging folder
JOURNAL_NAME = "journal.jsonl"
#: kernel file systems that are never an output folder
PSEUDO_FILESYSTEMS = ("/proc", "/sys", "/dev")
#: per-frame output folders (files named ``<stem>.<ext>``) of the run and its exports
PER_FRAME_FOLDERS = ("depth", "uncertainty", "depth_npy", "ply/sparse", "ply/dense")
#: outputs written once at the end of a run (removed from a staging folder before resuming)
RUN_END_OUTPUTS = ("frames.jsonl", "metrics.json", "trajectory.tum", "preview", "error", "thumbs", "report", "ply/sparse_map.ply")


class OutputMode(str, enum.Enum):
    """What to do with an ``--out`` that already holds a run (or a staging folder)."""

    NEW = "new"  # refuse a non-empty --out and an interrupted run of it
    OVERWRITE = "overwrite"  # replace a finished run atomically; discard an interrupted one
    RESUME = "resume"  # continue an interrupted run (or start one when there is none)


class OutputFolderError(InputError):
    """``--out`` cannot be used (the message says why and what to do)."""


def _real(path: Path) -> Path:
    return Path(os.path.realpath(path))


def resolve_out(out) -> Path:
    """``out`` as an absolute path, a symbolic link in its last component followed (so that
    the staging folder, the swap and every message name the same folder)."""
    out = Path(os.path.abspath(out))
    if os.path.islink(out):
        return _real(out)
    return out


def _inside(child: Path, parent: Path) -> bool:
    return child == parent or parent in child.parents


def _os_error(path: Path, exc: OSError, doing: str) -> OutputFolderError:
    why = {errno.ENAMETOOLONG: "name too long", errno.EACCES: "permission denied",
           errno.EPERM: "operation not permitted", errno.EROFS: "read-only file system",
           errno.ENOSPC: "no space left on device", errno.ENOTDIR: "a part of the path is a file",
           errno.ENOENT: "no such file or directory"}.get(exc.errno, exc.strerror or str(exc))
    return OutputFolderError(f"{path}: cannot {doing} ({why})")


def check_out_path(out, inputs: Iterable = ()) -> Path:
    """Refuse an output path that could hurt an input or cannot be a folder; write nothing.

    Args:
        out: the ``--out`` folder.
        inputs: paths the run reads (sequence folder, disparity folder, model, config file).

    Returns:
        ``out`` as an absolute path; a symbolic link in its last component is followed
        (:func:`resolve_out`).

    Raises:
        OutputFolderError: ``out`` is an existing file, a symbolic link to nothing, lies
            under /proc, /sys or /dev, is equal to or inside an input folder, contains an
            input, its staging folder would be, contain or lie in an input, or has a name
            longer than the file system allows.
    """
    given = Path(os.path.abspath(out))
    if os.path.islink(given) and not os.path.exists(given):
        raise OutputFolderError(f"{given}: is a symbolic link to {os.readlink(given)}, which does not exist; "
                                "vio-depth follows a link named by --out but never replaces the link itself "
                                "(create the target folder, or choose another --out)")
    out = resolve_out(given)
    if out.name in ("", ".", ".."):
        raise OutputFolderError(f"{out}: not usable as an output folder")
    real = _real(out)
    for fs in PSEUDO_FILESYSTEMS:
        if _inside(real, Path(fs)):
            raise OutputFolderError(f"{out}: lies under {fs}, a kernel file system, not an output folder")
    try:
        if out.exists() and not out.is_dir():
            raise OutputFolderError(f"{out}: exists and is not a folder (--out names a folder)")
    except OSError as exc:
        raise _os_error(out, exc, "use it as output folder") from None
    for given in inputs:
        if given is None or str(given) == "":
            continue
        src = _real(Path(given))
        if _inside(real, src):
            what = "is" if real == src else "lies inside"
            raise OutputFolderError(f"{out}: {what} the input {given}; vio-depth never writes into its inputs "
                                    "(choose another --out)")
        if _inside(src, real):
            raise OutputFolderError(f"{out}: contains the input {given}; a run may replace --out, so it must "
                                    "not hold any input (choose another --out)")
        for side in (staging_path(out), aside_path(out)):
            side_real = _real(side)
            if _inside(side_real, src) or _inside(src, side_real):
                raise OutputFolderError(f"{out}: its staging folder {side} would be, lie in or contain the input "
                                        f"{given}; vio-depth never writes into its inputs (choose another --out)")
    for part in out.parts:
        if len(os.fsencode(part)) > 255:
            raise OutputFolderError(f"{out}: cannot use it as output folder (name too long: "
                                    f"{len(os.fsencode(part))} bytes in one path component, at most 255)")
    return out


def staging_path(out) -> Path:
    """The staging folder of ``out``: ``.<name>.vio-depth-partial`` in the same parent
    (with a hash instead of the full name when that would exceed 255 bytes); next to the
    target when ``out`` is a symbolic link."""
    out = resolve_out(out)
    name = f".{out.name}{STAGING_SUFFIX}"
    if len(os.fsencode(name)) > 255:
        digest = hashlib.sha1(os.fsencode(out.name)).hexdigest()[:12]
        name = f".{os.fsencode(out.name)[:120].decode('utf-8', 'ignore')}-{digest}{STAGING_SUFFIX}"
    return out.parent / name


def is_run_folder(path) -> bool:
    """True when ``path`` holds a vio-depth run: it carries vio-depth's run marker
    (:mod:`vio_depth.io.marker`). A ``frames.jsonl`` alone proves nothing (issue 23)."""
    return read_marker(path, "run") is not None


def _listing(path: Path) -> list[str]:
    try:
        return os.listdir(path)
    except FileNotFoundError:
        return []
    except OSError as exc:
        raise _os_error(path, exc, "read the output folder") from None


# --------------------------------------------------------------------------- the folder
class OutputFolder:
    """The ``--out`` folder of one run and its staging folder (see the module docstring).

    Args:
        out: the ``--out`` folder.
        mode: :class:`OutputMode`.
        inputs: paths the run reads; ``out`` may not be, lie in or contain any of them.

    Usage: :meth:`claim` (creates and locks the staging folder, or re-opens an interrupted
    one), write into :attr:`staging`, :meth:`append` a journal line per completed frame,
    then :meth:`commit`; :meth:`release` on failure (keeps the staging folder).
    """

    def __init__(self, out, mode: OutputMode | str = OutputMode.NEW, inputs: Iterable = ()):
        self.mode = OutputMode(mode)
        self.out = check_out_path(out, inputs)
        self.staging = staging_path(self.out)
        self._lock_fd: int | None = None
        self._journal_fd: int | None = None
        #: the marker id of the finished run in ``out`` when the run started (None: ``out``
        #: was missing or empty); only that content is deleted after the swap
        self._replaces: str | None = None

    @property
    def journal(self) -> Path:
        return self.staging / JOURNAL_NAME

    # ------------------------------------------------------------------ checks
    def existing_run(self) -> bool:
        """True when ``out`` holds a finished run (it carries vio-depth's marker); raises when
        it holds anything else."""
        entries = _listing(self.out)
        if not entries:
            self._replaces = None
            return False
        ident = read_marker(self.out, "run")
        if ident is not None:
            self._replaces = ident
            return True
        old = (" (runs written by vio-depth 0.2.0 or earlier carry none: delete such a run yourself)"
               if (self.out / "frames.jsonl").is_file() else "")
        raise OutputFolderError(
            f"{self.out}: not empty ({len(entries)} entries) and holds no vio-depth run (no {RUN_MARKER} "
            f"marker){old}; vio-depth never replaces a folder it did not write (choose another --out, or empty "
            "it yourself)")

    def check_mode(self) -> None:
        """Refuse what the mode does not allow (a finished run without --overwrite/--resume)."""
        if self.existing_run() and self.mode == OutputMode.NEW:
            raise OutputFolderError(f"{self.out}: already holds a vio-depth run; give --overwrite to replace it "
                                    "or --resume to continue it")

    # ------------------------------------------------------------------ staging
    def _lock(self) -> None:
        try:
            fd = os.open(self.staging, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
        except OSError as exc:
            raise _os_error(self.staging, exc, "open the staging folder") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise OutputFolderError(f"{self.out}: another vio-depth run is writing it right now "
                                    f"(its staging folder {self.staging.name} is locked); wait for it to "
                                    "finish") from None
        self._lock_fd = fd

    def _make_staging(self) -> None:
        try:
            self.out.parent.mkdir(parents=True, exist_ok=True)
            self.staging.mkdir()
        except OSError as exc:
            raise _os_error(self.staging, exc, "create the staging folder next to --out") from None
        self._lock()
        try:
            write_marker(self.staging, "run")  # first, so that vio-depth recognises the folder as its own
        except OSError as exc:
            self.release()
            try:
                os.rmdir(self.staging)  # just created by this run, and empty
            except OSError:
                pass
            raise _os_error(self.staging, exc, "write into the staging folder") from None

    def _check_staging_is_ours(self) -> None:
        """Refuse a staging folder that vio-depth did not make (no marker, a link, a file):
        it is never continued nor deleted. A live run that has just made it (its marker not
        yet written) is reported as such."""
        if os.path.islink(self.staging) or not self.staging.is_dir():
            raise OutputFolderError(f"{self.staging}: has the name of --out's staging folder but is not a folder "
                                    "vio-depth made; vio-depth never deletes it (move it away, or choose another "
                                    "--out)")
        if read_marker(self.staging, "run") is None:
            self._lock()  # a live run that has just created it: "another run is writing"
            self.release()
            raise OutputFolderError(f"{self.staging}: has the name of --out's staging folder but carries no vio-depth "
                                    f"marker ({RUN_MARKER}); vio-depth never deletes it (move it away, or choose "
                                    "another --out)")

    def _discard_staging(self) -> None:
        self._lock()  # refuses when a live run holds it
        try:
            if read_marker(self.staging, "run") is None:  # checked again under the lock
                raise OutputFolderError(f"{self.staging}: carries no vio-depth marker; not deleted")
            shutil.rmtree(self.staging)
        except OSError as exc:
            raise _os_error(self.staging, exc, "remove the old staging folder") from None
        finally:
            self.release()

    def interrupted(self) -> bool:
        """True when an interrupted run left a staging folder with a journal. A staging
        folder of vio-depth's without one (a crash during the final swap) is removed; one
        that is not vio-depth's is refused (:class:`OutputFolderError`)."""
        if not os.path.lexists(self.staging):
            return False
        self._check_staging_is_ours()
        if self.journal.is_file():
            return True
        log.info("removing %s: left over from a finished swap", self.staging)
        self._discard_staging()
        return False

    def claim_new(self) -> None:
        """Start a fresh staging folder (discarding an interrupted run only with --overwrite)."""
        self.check_mode()
        if self.interrupted():
            self._lock()  # a run still working on it: say so, and never advise --resume
            self.release()
            if self.mode != OutputMode.OVERWRITE:
                raise OutputFolderError(
                    f"{self.out}: an interrupted run of it is kept in {self.staging.name}; give --resume to "
                    "continue it or --overwrite to start over")
            self._discard_staging()
        self._make_staging()

    def claim_interrupted(self) -> None:
        """Lock the staging folder of an interrupted run (``interrupted()`` must be True);
        ``out`` must still be empty, missing or a vio-depth run."""
        self._lock()
        try:
            self.existing_run()
        except BaseException:
            self.release()
            raise

    # ------------------------------------------------------------------ journal
    def start_journal(self, header: dict, records: list[dict] = ()) -> None:
        """(Re)write the journal with ``header`` and ``records``, then open it for appending."""
        lines = [json.dumps(header)] + [json.dumps(r) for r in records]
        write_bytes_atomic(self.journal, ("\n".join(lines) + "\n").encode())
        self._journal_fd = os.open(self.journal, os.O_WRONLY | os.O_APPEND)

    def append(self, record: dict) -> None:
        """Append one completed frame's record (one ``write`` call: a kill leaves whole lines)."""
        os.write(self._journal_fd, (json.dumps(record) + "\n").encode())

    def read_journal(self) -> tuple[dict | None, list[dict]]:
        """``(header, records)`` of the journal; a torn last line (a kill mid-write) is dropped."""
        try:
            data = self.journal.read_bytes()
        except OSError as exc:
            raise _os_error(self.journal, exc, "read the journal") from None
        header, records = None, []
        for raw in data.split(b"\n"):
            try:
                obj = json.loads(raw)
            except ValueError:
                break  # a torn line ends what is known
            if not isinstance(obj, dict):
                break
            if obj.get("record") == "run" and header is None and not records:
                header = obj
            elif obj.get("record") == "frame" and header is not None and obj.get("frame") == len(records):
                records.append(obj)
            else:
                break
        return header, records

    def prune(self, stems_to_drop: Iterable[str], depth_only: Iterable[str] = ()) -> None:
        """Prepare the staging folder for a resumed run: remove every per-frame file of
        ``stems_to_drop``, the depth files (not the sparse point clouds) of ``depth_only``,
        the outputs written at the end of a run, and temporary files."""
        drop, depth = set(stems_to_drop), set(depth_only)
        for folder in PER_FRAME_FOLDERS:
            d = self.staging / folder
            if not d.is_dir():
                continue
            for p in d.iterdir():
                if p.is_file() and (p.stem in drop or (p.stem in depth and folder != "ply/sparse")):
                    p.unlink()
        for name in RUN_END_OUTPUTS:
            p = self.staging / name
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()
        for p in self.staging.rglob("*.partial"):
            p.unlink()

    # ------------------------------------------------------------------ end
    def commit(self) -> None:
        """Remove the journal and move the staging folder into place (atomic replace)."""
        if self._journal_fd is not None:
            os.close(self._journal_fd)
            self._journal_fd = None
        try:
            self.journal.unlink(missing_ok=True)
            replace_folder(self.staging, self.out, self._replaces)
        except OSError as exc:
            raise _os_error(self.out, exc, "move the finished run into place") from None
        finally:
            self.release()

    def release(self) -> None:
        """Close the journal and unlock (the staging folder stays for --resume)."""
        if self._journal_fd is not None:
            os.close(self._journal_fd)
            self._journal_fd = None
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None
