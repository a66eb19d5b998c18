"""One reader for the line-based text tables of every dataset, with ``file:line`` errors.

Every loader reads its small text files (frame lists, trajectories, IMU samples,
calibration) through :func:`read_text_table`, so blank lines, ``#`` comments, non-UTF-8
bytes, wrong column counts and non-numeric or non-finite values are handled once and
always reported as :class:`~vio_core.errors.SequenceFormatError` naming the file and line.
Format-specific readers built on it live here too when more than one loader uses them:
the TUM trajectory format (:func:`read_tum_trajectory`, one quaternion tolerance;
:func:`format_tum_trajectory`) and
pose interpolation in time (:func:`interpolate_poses`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.checks import check_array
from vio_core.errors import SequenceFormatError
from vio_core.geometry import transform_to_tum
from vio_core.limits import MAX_TEXT_BYTES, read_limited, too_large

#: |norm - 1| of a quaternion in a trajectory file must be below this (4-decimal TUM
#: files are within 2e-4; anything larger is a wrong column order or a corrupt line)
QUATERNION_NORM_TOLERANCE = 1e-3
#: a pose whose position coordinate exceeds this (metres) is refused as corrupt: Earth-centred
#: (ECEF) and UTM coordinates stay below 1e7 m, so 1e8 m (100 000 km) admits every real
#: trajectory; larger values overflow the squares of the trajectory alignment (issue 23: a
#: ``tx = 1e300`` row hung the SVD of the Umeyama alignment)
MAX_POSITION_M = 1e8


@dataclass(frozen=True)
class TextTable:
    """The non-blank, non-comment lines of a text file, split into fields.

    Attributes:
        path: the file.
        rows: fields of each kept line (whitespace-separated strings).
        lines: 1-based line number of each row in the file.
    """

    path: Path
    rows: list[list[str]]
    lines: list[int]

    def __len__(self) -> int:
        return len(self.rows)

    def error(self, row: int | None, message: str) -> SequenceFormatError:
        """A :class:`SequenceFormatError` naming the file and the line of ``row`` (or no line)."""
        return SequenceFormatError(self.path, message, None if row is None else self.lines[row])

    def floats(self, columns: slice = slice(None), what: str = "value") -> np.ndarray:
        """(N, C) float64 of the ``columns`` of every row; non-numeric or non-finite -> error."""
        out = []
        for i, fields in enumerate(self.rows):
            try:
                values = [float(f) for f in fields[columns]]
            except ValueError:
                raise self.error(i, f"non-numeric {what} in {' '.join(fields)[:60]!r}") from None
            if not np.all(np.isfinite(values)):
                raise self.error(i, f"non-finite {what} in {' '.join(fields)[:60]!r}")
            out.append(values)
        return np.asarray(out, dtype=np.float64).reshape(len(out), -1)

    def column(self, index: int) -> list[str]:
        """The string field ``index`` of every row."""
        return [fields[index] for fields in self.rows]

    def check_positions(self, xyz: np.ndarray, what: str = "position") -> None:
        """Raise naming the first line whose ``xyz`` ((N, 3) metres, one row per table row)
        has a coordinate beyond :data:`MAX_POSITION_M`."""
        bad = np.flatnonzero(~np.all(np.abs(np.asarray(xyz, dtype=np.float64)) <= MAX_POSITION_M, axis=1))
        if len(bad):
            i = int(bad[0])
            raise self.error(i, f"{what} ({', '.join(f'{v:.3g}' for v in xyz[i])}) m is beyond the plausible "
                                f"{MAX_POSITION_M:.0e} m (a corrupt line?)")

    def check_increasing(self, t: np.ndarray, *, strict: bool = True) -> None:
        """Raise naming the first line whose time ``t[i]`` does not increase (strictly)."""
        d = np.diff(np.asarray(t, dtype=np.float64))
        bad = np.flatnonzero(d <= 0 if strict else d < 0)
        if len(bad):
            i = int(bad[0]) + 1
            raise self.error(i, f"timestamps must be {'strictly ' if strict else ''}increasing "
                                f"({t[i]:.6f} after {t[i - 1]:.6f})")


def read_text_table(path, what: str, *, layout: str | None = None, columns: int | None = None,
                    min_columns: int | None = None, allow_empty: bool = False,
                    delimiter: str | None = None) -> TextTable:
    """Read a whitespace-separated (or ``delimiter``-separated) text table.

    Args:
        path: the file.
        what: what the file holds, for messages ("frames", "trajectory", "calibration", ...).
        layout: the fields of a line, for messages ("timestamp image_path"; default: ``what``).
        columns: exact number of fields per line, or None.
        min_columns: least number of fields per line (extra fields are kept), or None.
        allow_empty: no error when no row remains.
        delimiter: field separator (``","`` for EuRoC csv files; fields are stripped of
            surrounding whitespace), or None for runs of whitespace.

    Returns:
        :class:`TextTable` of the lines that are neither blank nor start with ``#``.

    Raises:
        SequenceFormatError: missing or unreadable file, a file larger than
            :data:`vio_core.limits.MAX_TEXT_BYTES` (checked before reading it), bytes that are
            not UTF-8, a line with the wrong number of fields, or no rows (names the file and line).
    """
    path = Path(path)
    if not path.is_file():
        raise SequenceFormatError(path, f"{what} file not found")
    try:
        data, size = read_limited(path, MAX_TEXT_BYTES)
    except OSError as exc:
        raise SequenceFormatError(path, f"cannot read: {exc.strerror or exc}") from None
    if data is None:
        raise SequenceFormatError(path, too_large(size, MAX_TEXT_BYTES, f"a {what} file"))
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise SequenceFormatError(path, "not UTF-8 text", line) from None
    layout = what if layout is None else layout
    rows, lines = [], []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        fields = s.split() if delimiter is None else [f.strip() for f in s.split(delimiter)]
        if columns is not None and len(fields) != columns:
            raise SequenceFormatError(path, f"expected {columns} columns ({layout}), got {len(fields)}", lineno)
        if min_columns is not None and len(fields) < min_columns:
            raise SequenceFormatError(path, f"expected at least {min_columns} columns ({layout}), got {len(fields)}",
                                      lineno)
        rows.append(fields)
        lines.append(lineno)
    if not rows and not allow_empty:
        raise SequenceFormatError(path, f"no {what} rows")
    return TextTable(path, rows, lines)


def stays_inside(relative: str) -> bool:
    """True when the relative path ``relative`` names something inside its base folder: not
    absolute and no ``..`` that climbs above it (checked on the text, links are not followed)."""
    if not relative or os.path.isabs(relative):
        return False
    norm = os.path.normpath(relative)
    return norm != ".." and not norm.startswith(".." + os.sep)


def inside_name(name, path, where: str) -> str:
    """``name`` (read from the file ``path``, at ``where``) when it is a relative path that stays
    inside its base folder (:func:`stays_inside`), else :class:`SequenceFormatError`."""
    if not isinstance(name, str) or not stays_inside(name):
        raise SequenceFormatError(path, f"{where}: file name {name!r} points outside the dataset folder")
    return name


def read_numeric_table(path, ncols: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """``(values (N, ncols) float64, line numbers (N,))`` of a purely numeric table."""
    table = read_text_table(path, what, columns=ncols)
    return table.floats(what="value"), np.asarray(table.lines, dtype=np.int64)


def read_matrix(path, shape: tuple[int, int], what: str = "matrix") -> np.ndarray:
    """A ``shape`` matrix written as ``shape[0]`` lines of ``shape[1]`` numbers."""
    table = read_text_table(path, what, layout=f"{shape[0]}x{shape[1]} matrix row", columns=shape[1])
    if len(table) != shape[0]:
        raise table.error(None, f"expected {shape[0]} lines of {shape[1]} numbers ({what}), got {len(table)}")
    return table.floats(what=what)


def read_tum_trajectory(path) -> tuple[np.ndarray, np.ndarray]:
    """A TUM trajectory: ``t tx ty tz qx qy qz qw`` per line (extra columns are an error).

    Returns:
        t: (N,) seconds, strictly increasing.
        T: (N, 4, 4) transforms (as the file defines them, e.g. camera-to-world), metres.

    Raises:
        SequenceFormatError: wrong column count, non-numeric values, a position beyond
            :data:`MAX_POSITION_M`, a quaternion whose norm differs from 1 by more than
            :data:`QUATERNION_NORM_TOLERANCE`, or timestamps not strictly increasing (names
            the file and line).
    """
    table = read_text_table(path, "trajectory", layout="t tx ty tz qx qy qz qw", columns=8)
    rows = table.floats(what="value")
    table.check_positions(rows[:, 1:4])
    norms = np.linalg.norm(rows[:, 4:8], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if len(bad):
        raise table.error(int(bad[0]), f"quaternion norm {norms[bad[0]]:.6f} is not 1")
    table.check_increasing(rows[:, 0])
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(rows[:, 4:8] / norms[:, None]).as_matrix()
    T[:, :3, 3] = rows[:, 1:4]
    return rows[:, 0].copy(), T


def format_tum_trajectory(t, T_w_c, header: str = "camera-to-world, metres", time_decimals: int = 6) -> str:
    """TUM text of ``t: (N,)`` seconds and ``T_w_c: (N, 4, 4)`` poses: a ``#`` header line,
    then ``t tx ty tz qx qy qz qw`` per pose (``time_decimals`` decimals of a second)."""
    t = check_array("t", t, (None,), finite=True)
    T_w_c = check_array("T_w_c", T_w_c, (len(t), 4, 4), finite=True)
    lines = [f"# timestamp tx ty tz qx qy qz qw ({header})\n"]
    for ti, T in zip(t, T_w_c):
        lines.append(f"{ti:.{time_decimals}f} " + " ".join(f"{x:.9f}" for x in transform_to_tum(T)) + "\n")
    return "".join(lines)


def write_tum_trajectory(path, t, T_w_c, header: str = "camera-to-world, metres") -> None:
    """Write ``t: (N,)`` seconds and ``T_w_c: (N, 4, 4)`` poses in TUM format."""
    text = format_tum_trajectory(t, T_w_c, header)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text)


def associate_nearest(t_query, t_ref, max_difference: float) -> np.ndarray:
    """Index of the nearest reference timestamp for each query, -1 when none is close enough.

    Args:
        t_query: (N,) seconds.
        t_ref: (M,) seconds, non-decreasing.
        max_difference: seconds.

    Returns:
        (N,) int64 indices into ``t_ref`` (-1 = farther than ``max_difference``).
    """
    q = check_array("t_query", t_query, (None,), finite=True)
    r = check_array("t_ref", t_ref, (None,), finite=True)
    if len(r) == 0:
        return np.full(len(q), -1, np.int64)
    hi = np.clip(np.searchsorted(r, q), 1, max(len(r) - 1, 1))
    lo = hi - 1
    if len(r) == 1:
        best = np.zeros(len(q), np.int64)
    else:
        best = np.where(np.abs(r[lo] - q) <= np.abs(r[hi] - q), lo, hi)
    return np.where(np.abs(r[best] - q) <= max_difference, best, -1).astype(np.int64)


def interpolate_poses(t_query, t_ref, T_ref, max_difference: float, *,
                      bracketed_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Poses at ``t_query`` interpolated between the reference samples around each time.

    Translation is interpolated linearly and rotation along the geodesic. A query needs
    a reference sample within ``max_difference``; when the query is not bracketed by
    two samples (or the bracketing gap exceeds ``2 * max_difference``) the nearest
    sample's pose is used -- unless ``bracketed_only``, when such a query gets no pose
    (never extrapolated; a query at a sample's exact time still takes that sample).

    Args:
        t_query: (N,) seconds.
        t_ref: (M,) seconds, non-decreasing.
        T_ref: (M, 4, 4) poses at ``t_ref``.
        max_difference: seconds.
        bracketed_only: no nearest-sample fallback (see above).

    Returns:
        ``(T (N, 4, 4), ok (N,) bool)``; rows with ``ok`` False are identity.
    """
    q = check_array("t_query", t_query, (None,), finite=True)
    r = check_array("t_ref", t_ref, (None,), finite=True)
    T = check_array("T_ref", T_ref, (len(r), 4, 4), finite=True)
    nearest = associate_nearest(q, r, max_difference)
    ok = nearest >= 0
    if bracketed_only and len(r):
        ok &= r[np.maximum(nearest, 0)] == q  # exact sample times; bracketed queries join below
    out = np.tile(np.eye(4), (len(q), 1, 1))
    out[ok] = T[nearest[ok]]
    if len(r) >= 2:
        j = np.clip(np.searchsorted(r, q, side="right") - 1, 0, len(r) - 2)
        gap = r[j + 1] - r[j]
        brk = (nearest >= 0) & (r[j] <= q) & (q <= r[j + 1]) & (gap > 0) & (gap <= 2 * max_difference)
        ok |= brk
        if brk.any():
            jb = j[brk]
            a = (q[brk] - r[jb]) / gap[brk]
            R0 = Rotation.from_matrix(T[jb, :3, :3])
            R1 = Rotation.from_matrix(T[jb + 1, :3, :3])
            step = (R0.inv() * R1).as_rotvec()
            out[brk, :3, :3] = (R0 * Rotation.from_rotvec(step * a[:, None])).as_matrix()
            out[brk, :3, 3] = (1 - a)[:, None] * T[jb, :3, 3] + a[:, None] * T[jb + 1, :3, 3]
    return out, ok


def yaml_float(value) -> float | None:
    """A finite float from a YAML scalar, or None. Strings such as ``2e-05`` count: YAML 1.1
    (PyYAML) reads exponents without a decimal point as strings."""
    if isinstance(value, bool):
        return None
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            return None
    if not isinstance(value, (int, float)) or not np.isfinite(value):
        return None
    return float(value)
