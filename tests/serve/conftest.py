"""Serve fixtures: the tiny random-weight checkpoint and its pipeline (tests/conftest.py: ``tiny_pipe``; helpers:
serve_helpers.py)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def checkpoint(tiny_checkpoint):
    return tiny_checkpoint


@pytest.fixture(scope="module")
def pipe(tiny_pipe):
    return tiny_pipe()
