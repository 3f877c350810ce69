"""Fixtures shared by the test modules."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from facegeo import load_model
from facegeo.layout_cache import LAYOUT_CACHE_ENV
from facegeo.morphable_model import MorphableModel


@pytest.fixture(scope="session")
def model() -> MorphableModel:
    """The bundled ICT-FaceKit model (``load_model()``; cached, so every test sees the same object)."""
    return load_model()


@pytest.fixture(scope="session", autouse=True)
def layout_cache(tmp_path_factory) -> Iterator[Path]:
    """The session's layout cache (:mod:`facegeo.layout_cache`): a temporary folder named by
    ``FACEGEO_LAYOUT_CACHE``, which the commands the tests start inherit, so that no test writes
    rasters or layout priors into ``~/.cache``. Only that cache moves: dlib's converted predictor
    (``$XDG_CACHE_HOME/facegeo``, seconds to convert) is still found where it is."""
    folder = tmp_path_factory.mktemp("layout-cache")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(LAYOUT_CACHE_ENV, str(folder))
        yield folder
