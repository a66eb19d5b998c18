"""Issue 12, case 6: file lists may not point outside their sequence folder."""

import pytest

from vio_depth.io.tables import stays_inside


@pytest.mark.parametrize("path, inside", [
    ("images/0.jpg", True), ("./images/0.jpg", True), ("a/../b.jpg", True), ("x", True),
    ("../outside.jpg", False), ("images/../../x.jpg", False), ("..", False), ("/etc/passwd", False), ("", False),
])
def test_stays_inside(path, inside):
    assert stays_inside(path) is inside
