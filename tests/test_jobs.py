"""The one-photo jobs behind ``facegeo fit`` / ``facegeo reconstruct`` as library functions."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from facegeo.errors import InputError
from facegeo.jobs import FIT_FILES, FitOptions, ReconstructOptions, fit_into_folder, loaded_resources
from facegeo.staged_output import MANIFEST

PHOTO = Path(__file__).resolve().parents[1] / "assets" / "photos" / "astronaut.png"


@pytest.mark.parametrize("bad, field", [
    ({"landmarks": "sift"}, "landmarks"),
    ({"refine": True}, "refine"),
    ({"maps": ("albedo", "gloss")}, "maps"),
    ({"maps": ()}, "maps"),
    ({"formats": ("obj",)}, "formats"),
    ({"backend": "default", "weights": Path("w")}, "weights"),
    ({"upscale": 3}, "upscale"),
    ({"subdiv": 4}, "subdiv"),
    ({"parts": "torso"}, "parts"),
])
def test_reconstruct_options_name_the_bad_field(bad: dict, field: str) -> None:
    with pytest.raises(InputError, match=field):
        ReconstructOptions(**bad)


def test_resources_are_loaded_once_per_process() -> None:
    first = loaded_resources(None, None, False, "hybrid")
    assert loaded_resources(None, None, False, "hybrid") is first
    assert first[1] is None


def test_fit_into_folder_writes_the_files_it_reports(tmp_path: Path) -> None:
    record = fit_into_folder(PHOTO, tmp_path / "fit", FitOptions(photometric=False))
    assert sorted(p.name for p in (tmp_path / "fit").iterdir()) == sorted([*FIT_FILES, MANIFEST])
    assert sorted(FIT_FILES) == sorted(record.files)
    written = json.loads((tmp_path / "fit" / "fit.json").read_text())
    assert written["landmark_rms_px"] == pytest.approx(record.landmark_rms_px)
    assert 0 < record.landmark_rms_percent_iod < 6
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # nothing staged left behind
