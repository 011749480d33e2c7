"""Fixtures for the AppTest page tests; the helpers live in apphelpers.py (import from there)."""

from __future__ import annotations

import pytest
from apphelpers import _open


@pytest.fixture
def open_page():
    """``open_page(path, **query)``: start at app.py with URL query parameters, switch, run."""
    return _open
