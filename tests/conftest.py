"""Fixtures shared by the test modules."""

from __future__ import annotations

import pytest

from facegeo import load_model
from facegeo.morphable_model import MorphableModel


@pytest.fixture(scope="session")
def model() -> MorphableModel:
    """The bundled ICT-FaceKit model (``load_model()``; cached, so every test sees the same object)."""
    return load_model()
