"""vio_core.environ: variables set for a block and restored, also after an exception."""

import os

import pytest

from vio_core import environ


def test_sets_then_restores_set_and_unset_variables(monkeypatch):
    monkeypatch.setenv("VIO_TEST_A", "before")
    monkeypatch.delenv("VIO_TEST_B", raising=False)
    with environ({"VIO_TEST_A": "1", "VIO_TEST_B": 2}):
        assert os.environ["VIO_TEST_A"] == "1" and os.environ["VIO_TEST_B"] == "2"
    assert os.environ["VIO_TEST_A"] == "before" and "VIO_TEST_B" not in os.environ


def test_restores_after_an_exception(monkeypatch):
    monkeypatch.delenv("VIO_TEST_C", raising=False)
    with pytest.raises(RuntimeError):
        with environ({"VIO_TEST_C": "x"}):
            raise RuntimeError("boom")
    assert "VIO_TEST_C" not in os.environ
