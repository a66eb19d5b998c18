"""The shared text-table reader: comma-separated tables and bracketed-only pose interpolation."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vio_core.errors import SequenceFormatError
from vio_depth.io.tables import interpolate_poses, read_text_table


def test_comma_separated_table_strips_fields_and_names_the_line(tmp_path):
    path = tmp_path / "data.csv"
    path.write_text("#timestamp [ns],filename\n1, a.png\n2,b.png \n")
    table = read_text_table(path, "images", delimiter=",", columns=2)
    assert table.rows == [["1", "a.png"], ["2", "b.png"]] and table.lines == [2, 3]
    path.write_text("#t,x\n1,2\n3 4\n")  # whitespace is not a separator here
    with pytest.raises(SequenceFormatError, match=r"data\.csv:3: expected 2 columns"):
        read_text_table(path, "samples", delimiter=",", columns=2)


def _line():
    t_ref = np.array([1.0, 1.005, 1.010, 1.5])
    T = np.tile(np.eye(4), (4, 1, 1))
    T[:, 0, 3] = [0.0, 1.0, 2.0, 3.0]
    T[1, :3, :3] = Rotation.from_rotvec([0, 0, 0.2]).as_matrix()
    return t_ref, T


def test_bracketed_only_never_extrapolates():
    t_ref, T = _line()
    q = [0.999, 1.0, 1.0025, 1.2, 1.5, 1.6]
    out, ok = interpolate_poses(q, t_ref, T, 0.01, bracketed_only=True)
    assert ok.tolist() == [False, True, True, False, True, False]  # 1.2 s: the bracketing gap is 0.49 s
    assert out[2, 0, 3] == pytest.approx(0.5)
    assert Rotation.from_matrix(out[2, :3, :3]).magnitude() == pytest.approx(0.1)
    np.testing.assert_array_equal(out[~ok], np.tile(np.eye(4), (3, 1, 1)))
    # the default takes the nearest sample within max_difference instead (0.999 s -> the 1.0 s pose)
    near, ok_near = interpolate_poses(q, t_ref, T, 0.01)
    assert ok_near.tolist() == [True, True, True, False, True, False]
    np.testing.assert_array_equal(near[0], T[0])
    np.testing.assert_allclose(near[ok], out[ok])
