"""The command's entry point gives OpenBLAS one thread unless told otherwise."""

from __future__ import annotations

import os

import pytest

from ncmeasure.__main__ import main


def _version(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("sys.argv", ["ncmeasure", "--version"])
    main()


def test_one_blas_thread_by_default(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "")  # restored after the test
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")
    _version(monkeypatch)
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"


def test_a_given_thread_count_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    _version(monkeypatch)
    assert os.environ["OPENBLAS_NUM_THREADS"] == "2"
