"""Failure behaviour (issue 16), by class of fault: bad options and output locations, signals
during writing, resource exhaustion, partial multi-file outputs, degenerate and non-finite
numeric input, wrong-but-plausible fits. Every command-line case: exit status 2 (or 128 + the
signal), exactly one line on stderr naming the file or option, no traceback, nothing left."""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import resource
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from facegeo.asset import Asset
from facegeo.assets import asset_path
from facegeo.camera import Camera, euler_from_rotation
from facegeo.cli import main
from facegeo.errors import InputError, NoFaceError, OutputError
from facegeo.export.asset_io import load_asset, save_asset
from facegeo.export.writers import export_asset
from facegeo.fitting.checks import MAX_RMS_PERCENT_IOD, check_fit
from facegeo.fitting import fit, fit_landmarks
from facegeo.landmarks.scheme import inter_ocular_distance
from facegeo.photo import Photo, load_photo
from facegeo.staged_output import TEMP_PREFIX, StagedOutput
from test_export_support import grid_mesh, synthetic_maps
from test_shading import call, make_inputs

PHOTO = asset_path("photos/astronaut.png")


def run(args, capsys):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line(err: str, *names: str) -> None:
    assert err.count("\n") == 1 and err.startswith("facegeo: "), err
    assert "Traceback" not in err
    for name in names:
        assert name in err, (name, err)


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(f"{TEMP_PREFIX}*"))


@pytest.fixture(scope="module")
def asset_dir(tmp_path_factory) -> Path:
    """A small asset folder (a 4×4 quad grid with 32² maps) for ``facegeo export``."""
    v, f, uv, uvf = grid_mesh(4)
    return save_asset(Asset(v, f, uv, uvf, maps=synthetic_maps(32)), tmp_path_factory.mktemp("asset") / "asset")


@pytest.fixture
def no_fit(monkeypatch):
    """Fail the test if a fit starts: these errors must come before any work."""

    def refuse(*args, **kwargs):
        raise AssertionError("the fit ran before the options were checked")

    monkeypatch.setattr("facegeo.fitting.fit", refuse)
    monkeypatch.setattr("facegeo.pipeline.reconstruct_with_fit", refuse)


# -- bad options and output locations: checked before the fit --------------------------------

LONG = "x" * 300


@pytest.mark.parametrize(
    "args,named",
    [
        (["fit", PHOTO, "-o", "{out}", "--max-side", "0"], "--max-side"),
        (["fit", PHOTO, "-o", "{out}", "--max-side", "10"], "--max-side"),
        (["fit", PHOTO, "-o", "{out}", "--focal", "0"], "--focal"),
        (["fit", PHOTO, "-o", "{out}", "--focal", "nan"], "--focal"),
        (["unwrap", PHOTO, "-o", "{out}", "--focal=-inf"], "--focal"),
        (["fit", PHOTO, "-o", "{out}", "--max-side", "ten"], "--max-side"),  # argparse's own errors: one line too
        (["reconstruct", PHOTO, "-o", "{out}", "--format", ","], "--format"),
        (["reconstruct", PHOTO, "-o", "{out}", "--maps", ""], "--maps"),
        (["fit", PHOTO, "-o", "{out}/" + LONG], "NAME_MAX"),
        (["reconstruct", PHOTO, "-o", "{out}/" + LONG], "NAME_MAX"),
        (["fit", PHOTO, "-o", "{file}/out"], "is a file"),
        (["reconstruct", PHOTO, "-o", "{file}"], "an existing file"),
    ],
    ids=["max-side-0", "max-side-10", "focal-0", "focal-nan", "focal-inf", "max-side-text", "format-empty", "maps-empty",
         "fit-name-max", "reconstruct-name-max", "parent-is-file", "out-is-file"],
)
def test_bad_options_and_locations_fail_before_the_fit(tmp_path, capsys, no_fit, args, named):
    (tmp_path / "file").write_text("x")
    argv = [str(a).format(out=tmp_path / "out", file=tmp_path / "file") for a in args]
    try:
        code, out, err = run(argv, capsys)
    except SystemExit as exit_:  # argparse
        code, (out, err) = exit_.code, capsys.readouterr()
    assert code == 2 and out == ""
    assert_one_line(err, named)
    assert not (tmp_path / "out").exists() and leftovers(tmp_path) == []
    assert (tmp_path / "file").read_text() == "x"


def test_a_folder_that_is_not_an_earlier_output_is_refused_untouched(tmp_path, capsys, no_fit):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    code, _, err = run(["fit", PHOTO, "-o", out], capsys)
    assert code == 2
    assert_one_line(err, str(out), "notes.txt", "earlier facegeo output")
    assert [p.name for p in out.iterdir()] == ["notes.txt"]


@pytest.mark.parametrize(
    "output,fmt,named",
    [
        ("{tmp}/" + LONG + ".glb", None, "NAME_MAX"),
        ("{tmp}/file/face.glb", None, "is a file"),
        ("{tmp}/out/face", ",", "--format"),
        ("{tmp}/out/face", "usdz,fbx", "'fbx'"),
        ("{tmp}/out/face.obj", None, "suffix"),
    ],
    ids=["name-max", "parent-is-file", "format-empty", "format-unknown", "suffix"],
)
def test_export_options_fail_cleanly(tmp_path, capsys, asset_dir, output, fmt, named):
    (tmp_path / "file").write_text("x")
    argv = ["export", asset_dir, "-o", output.format(tmp=tmp_path)] + (["--format", fmt] if fmt else [])
    code, _, err = run(argv, capsys)
    assert code == 2
    assert_one_line(err, named)
    assert not (tmp_path / "out").exists() and leftovers(tmp_path) == []


def test_an_earlier_output_holding_the_photo_or_the_cwd_is_not_replaced(tmp_path, capsys, monkeypatch, no_fit):
    out = tmp_path / "out"
    out.mkdir()
    (out / "fit.json").write_text("{}")
    photo = out / "me.png"
    photo.write_bytes(Path(PHOTO).read_bytes())
    code, _, err = run(["reconstruct", photo, "-o", out], capsys)
    assert code == 2
    assert_one_line(err, "-o", "does not hold the inputs")
    monkeypatch.chdir(out)
    code, _, err = run(["fit", tmp_path / "elsewhere.png", "-o", "."], capsys)
    assert code == 2
    assert_one_line(err, "other than the current one")
    assert sorted(p.name for p in out.iterdir()) == ["fit.json", "me.png"]


def test_rerun_into_an_earlier_output_leaves_exactly_one_run(tmp_path):
    out = tmp_path / "out"
    with StagedOutput(out, replace=True) as stage:
        for name in ("fit.json", "face.usdz", "preview.png", "textures/albedo.png"):
            stage.path(name).write_text("old")
    with StagedOutput(out, replace=True) as stage:
        stage.path("fit.json").write_text("new")
        stage.path("mesh.obj").write_text("new")
    assert sorted(p.name for p in out.rglob("*")) == ["fit.json", "mesh.obj"]
    assert (out / "fit.json").read_text() == "new"
    assert leftovers(tmp_path) == []
    # a failed run leaves the earlier output exactly as it was
    with pytest.raises(RuntimeError), StagedOutput(out, replace=True) as stage:
        stage.path("fit.json").write_text("broken")
        raise RuntimeError("stage failed")
    assert sorted(p.name for p in out.rglob("*")) == ["fit.json", "mesh.obj"]
    assert (out / "fit.json").read_text() == "new" and leftovers(tmp_path) == []


# -- signals during writing -----------------------------------------------------------------


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_while_writing_leaves_nothing_and_prints_one_line(tmp_path, capsys, monkeypatch, asset_dir, signum):
    import facegeo.export.writers as writers

    real = writers.export_asset
    staged = []

    def write_then_signal(asset, path, **kwargs):
        written = real(asset, path, **kwargs)
        staged.append(sorted(p.name for p in Path(path).parent.iterdir()))
        os.kill(os.getpid(), signum)  # delivered to this (main) thread at the next bytecode
        time.sleep(5)  # pragma: no cover - the handler raises first
        return written

    monkeypatch.setattr(writers, "export_asset", write_then_signal)
    before = signal.getsignal(signum)
    out = tmp_path / "out" / "face"
    code, stdout, err = run(["export", asset_dir, "-o", out, "--format", "glb,usda"], capsys)
    assert code == 128 + signum and stdout == ""
    assert_one_line(err, "interrupted", signal.Signals(signum).name)
    assert staged == [["face.glb"]]  # the signal came while the staging folder held a file
    assert not (tmp_path / "out").exists() and leftovers(tmp_path) == []
    assert signal.getsignal(signum) is before  # main() restores the handlers it replaced


SLOW_EXPORT = """
import pathlib, sys, time
import facegeo.export.writers as writers
from facegeo.cli import main
real = writers.export_asset
def slow(asset, path, **kwargs):
    written = real(asset, path, **kwargs)
    pathlib.Path(sys.argv[1]).write_text("staged")
    time.sleep(120)
writers.export_asset = slow
sys.exit(main(sys.argv[2:]))
"""


def test_sigkill_leftovers_are_removed_by_the_next_run(tmp_path, capsys, asset_dir):
    flag, out = tmp_path / "flag", tmp_path / "out" / "face"
    proc = subprocess.Popen([sys.executable, "-c", SLOW_EXPORT, str(flag), "export", str(asset_dir), "-o", str(out),
                             "--format", "glb,usda"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not flag.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert flag.exists(), proc.communicate()[1]
        proc.kill()
        proc.wait()
    finally:
        if proc.poll() is None:  # pragma: no cover
            proc.kill()
            proc.wait()
    stale = leftovers(tmp_path)
    assert stale and all(name.startswith(f"{TEMP_PREFIX}{proc.pid}-") for name in stale)
    code, _, err = run(["export", asset_dir, "-o", out, "--format", "glb,usda"], capsys)
    assert code == 0, err
    assert leftovers(tmp_path) == []
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["face.glb", "face.usda", "face_textures"]


# -- resource exhaustion --------------------------------------------------------------------


def _file_size_limit(limit: int):
    def apply() -> None:  # Python ignores SIGXFSZ, so writes past the limit fail with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


def test_file_size_limit_is_one_line_and_leaves_nothing(tmp_path, asset_dir):
    out = tmp_path / "out" / "face"
    proc = subprocess.run([sys.executable, "-m", "facegeo.cli", "export", str(asset_dir), "-o", str(out), "--format", "usda,glb"],
                          capture_output=True, text=True, preexec_fn=_file_size_limit(2048), timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert_one_line(proc.stderr, "out/face.", "too large")
    assert not (tmp_path / "out").exists() and leftovers(tmp_path) == []


def test_full_disk_names_the_final_file_and_leaves_nothing(tmp_path, monkeypatch):
    def full(self, data):
        raise OSError(errno.ENOSPC, "No space left on device", str(self))

    monkeypatch.setattr(Path, "write_bytes", full)
    v, f, uv, uvf = grid_mesh(2)
    with pytest.raises(OutputError, match="no space left") as caught:
        save_asset(Asset(v, f, uv, uvf, maps=synthetic_maps(8)), tmp_path / "asset")
    assert str(tmp_path / "asset" / "albedo.png") in str(caught.value)  # not the staging folder's name
    assert list(tmp_path.iterdir()) == []


# -- partial multi-file outputs -------------------------------------------------------------


def test_multi_format_export_is_all_or_nothing(tmp_path, capsys, asset_dir):
    out = tmp_path / "out"
    (out / "face.glb").mkdir(parents=True)  # the second format's file cannot be written
    code, _, err = run(["export", asset_dir, "-o", out / "face", "--format", "usdz,glb"], capsys)
    assert code == 2
    assert_one_line(err, "face.glb", "an existing directory")
    assert sorted(p.name for p in out.iterdir()) == ["face.glb"] and leftovers(tmp_path) == []


def test_commit_checks_every_destination_before_moving_any(tmp_path):
    out = tmp_path / "out"
    (out / "b.txt").mkdir(parents=True)  # appears in the way while the run is going on
    with pytest.raises(InputError, match="b.txt"), StagedOutput(out) as stage:
        stage.path("a.txt").write_text("a")
        stage.path("b.txt").write_text("b")
    assert sorted(p.name for p in out.iterdir()) == ["b.txt"] and leftovers(tmp_path) == []


# -- degenerate and non-finite numeric input ------------------------------------------------


@pytest.mark.parametrize("name,where", [("normal_ts", (0, 2, 1, 1)), ("light_dirs", (1, 0, 0)), ("camera_pos", (0, 2))])
def test_shade_ggx_refuses_non_finite_input_by_name(name, where):
    inputs = make_inputs()
    inputs[name][where] = float("nan")
    with pytest.raises(InputError, match=f"shade_ggx: {name}: expected finite values, found 1 of"):
        call(inputs)
    with pytest.raises(InputError, match="ambient"):
        call({**make_inputs(), "ambient": float("inf")})


def test_export_revalidates_an_asset_changed_after_construction(tmp_path):
    v, f, uv, uvf = grid_mesh(2)
    asset = Asset(v, f, uv, uvf, maps=synthetic_maps(8))
    asset.maps["normal"][3, 4] = np.nan
    for target in ("face.glb", "face.usda"):
        with pytest.raises(InputError, match=r"maps\['normal'\]: expected finite values"):
            export_asset(asset, tmp_path / target)
    with pytest.raises(InputError, match=r"maps\['normal'\]"):
        save_asset(asset, tmp_path / "asset")
    asset.maps["normal"][3, 4] = (0.0, 0.0, 1.0)
    asset.constants = {}
    asset.maps.pop("roughness")
    asset.constants["roughness"] = float("nan")
    with pytest.raises(InputError, match=r"constants\['roughness'\]"):
        export_asset(asset, tmp_path / "face.glb")
    assert list(tmp_path.iterdir()) == []


def test_non_finite_map_encoding_is_refused_without_warnings(tmp_path, asset_dir):
    import shutil

    copy = Path(shutil.copytree(asset_dir, tmp_path / "asset"))
    doc = json.loads((copy / "asset.json").read_text())
    doc["maps"]["displacement"]["scale"] = float("inf")
    (copy / "asset.json").write_text(json.dumps(doc))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no NumPy RuntimeWarning on the way to the error
        with pytest.raises(InputError, match="maps.displacement.scale: expected a finite number"):
            load_asset(copy)


def test_truncated_map_png_is_one_message_without_libpng_noise(tmp_path, capfd, asset_dir):
    import shutil

    copy = Path(shutil.copytree(asset_dir, tmp_path / "asset"))
    data = (copy / "normal.png").read_bytes()
    (copy / "normal.png").write_bytes(data[: len(data) // 2])
    capfd.readouterr()
    code = main(["export", str(copy), "-o", str(tmp_path / "face.glb")])
    _, err = capfd.readouterr()
    assert code == 2
    assert_one_line(err, "normal.png", "a readable PNG file")
    assert "libpng" not in err


def test_litert_prints_nothing_on_stderr(capfd):
    from facegeo.landmarks.mediapipe_mesh import MediaPipeFaceMesh

    capfd.readouterr()
    faces = MediaPipeFaceMesh()(load_photo(PHOTO).image)  # a fresh instance: both interpreters created
    _, err = capfd.readouterr()
    assert len(faces) == 1 and err == ""


@pytest.mark.parametrize(
    "points,expected",
    [
        (np.full((88, 2), 100.0), "spread over a face"),  # all at one pixel (solvePnP failed in OpenCV)
        (np.full((88, 2), 1e15) + np.arange(176).reshape(88, 2), "within 1 image size"),  # a face 1e12 mm behind the camera
        (np.stack([np.linspace(50, 450, 88), np.full(88, 200.0)], axis=1), "points on a line"),
    ],
    ids=["one-pixel", "1e15-px", "on-a-line"],
)
def test_fit_landmarks_refuses_degenerate_points(model, points, expected):
    with pytest.raises(InputError, match=expected):
        fit_landmarks(model, points, Camera.for_image(512, 512))


# -- wrong-but-plausible fits ---------------------------------------------------------------


@pytest.fixture(scope="module")
def astronaut():
    return load_photo(PHOTO)


@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_points_found_on_a_turned_copy_map_back_exactly(k):
    from facegeo.landmarks.detectors import _turn_back

    image = np.zeros((5, 7), np.uint8)
    image[1, 5] = 255  # row 1, column 5: centre (5.5, 1.5) in corner-origin pixels
    turned = np.rot90(image, k)
    row, col = np.argwhere(turned == 255)[0]
    np.testing.assert_array_equal(_turn_back(np.array([[col + 0.5, row + 0.5]]), k, turned.shape), [[5.5, 1.5]])


@pytest.mark.parametrize("quarter_turns", [1, 2, 3])
def test_turned_photo_is_fitted_upright(model, astronaut, quarter_turns):
    image = np.ascontiguousarray(np.rot90(astronaut.image, quarter_turns))
    result = fit(image, model, photometric=False)
    roll = euler_from_rotation(result.rotation)[2]
    expected = (-4.0 + 90.0 * quarter_turns + 180.0) % 360.0 - 180.0  # the upright fit's roll is about −4°
    assert abs((roll - expected + 180.0) % 360.0 - 180.0) < 5.0, roll
    assert 100.0 * result.landmark_rms_px / inter_ocular_distance(result.landmarks) <= 3.0
    assert any("the face is upright with the photo turned" in note for note in result.info["notes"])


def test_landmarks_the_model_cannot_follow_are_refused(model, astronaut):
    good = fit(astronaut, model, photometric=False)
    check_fit(good, astronaut)  # the correct fit passes
    iod = inter_ocular_distance(good.landmarks)
    wrong = dataclasses.replace(good, landmark_rms_px=1.01 * MAX_RMS_PERCENT_IOD * iod / 100.0)
    with pytest.raises(NoFaceError, match="landmarks the face model can follow"):
        check_fit(wrong, astronaut)
    behind = dataclasses.replace(good, vertices=good.vertices * np.array([1, 1, -1], np.float32))
    with pytest.raises(InputError, match="in front of the camera"):
        check_fit(behind, astronaut)
    nan = dataclasses.replace(good, gamma=np.full_like(good.gamma, np.nan))
    with pytest.raises(InputError, match="fit gamma: expected finite values"):
        check_fit(nan, astronaut)


def test_transparent_face_is_refused(model, astronaut, tmp_path):
    h, w = astronaut.image.shape[:2]
    opacity = np.ones((h, w), np.float32)
    opacity[60:300, 150:330] = 0.0  # the face (its box is about x 170..310, y 90..280)
    see_through = Photo(image=astronaut.image, path="see-through.png", scale=1.0, original_size=(w, h), opacity=opacity)
    with pytest.raises(NoFaceError, match="see-through.png: alpha channel: expected an opaque face"):
        fit(see_through, model, photometric=False)
    # load_photo keeps the alpha channel for this check
    rgba = np.dstack([astronaut.image, (opacity * 255).astype(np.uint8)])
    Image.fromarray(rgba, "RGBA").save(tmp_path / "rgba.png")
    loaded = load_photo(tmp_path / "rgba.png")
    np.testing.assert_array_equal(loaded.opacity, opacity)
    assert load_photo(PHOTO).opacity is None
