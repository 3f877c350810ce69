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
from facegeo.fitting.checks import MAX_LANDMARK_ERROR_PERCENT, check_fit, landmark_error_percent
from facegeo.fitting import fit, fit_landmarks
from facegeo.landmarks.scheme import inter_ocular_distance
from facegeo.photo import Photo, load_photo
from facegeo.output_lock import LOCK_PREFIX
from facegeo.staged_output import MANIFEST, TEMP_PREFIX, StagedOutput
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
    assert sorted(p.name for p in out.rglob("*")) == [MANIFEST, "fit.json", "mesh.obj"]
    assert (out / "fit.json").read_text() == "new"
    assert leftovers(tmp_path) == []
    # a failed run leaves the earlier output exactly as it was
    with pytest.raises(RuntimeError), StagedOutput(out, replace=True) as stage:
        stage.path("fit.json").write_text("broken")
        raise RuntimeError("stage failed")
    assert sorted(p.name for p in out.rglob("*")) == [MANIFEST, "fit.json", "mesh.obj"]
    assert (out / "fit.json").read_text() == "new" and leftovers(tmp_path) == []


# -- re-runs and concurrent runs, with real processes --------------------------------------------

#: ``facegeo ARGS...`` whose job waits, once it holds its output's lock, for FLAG to go: with
#: ``at=photo`` before reading the photo, with ``at=overlay`` while its files are staged.
PAUSED = """
import pathlib, sys, time
import facegeo.overlay, facegeo.photo
from facegeo.cli import main
at, flag = sys.argv[1], pathlib.Path(sys.argv[2])
module, name = (facegeo.photo, "load_photo") if at == "photo" else (facegeo.overlay, "draw_overlay")
real = getattr(module, name)
def paused(*args, **kwargs):
    flag.write_text("inside")
    while flag.exists():
        time.sleep(0.05)
    return real(*args, **kwargs)
setattr(module, name, paused)
sys.exit(main(sys.argv[3:]))
"""

FIT = ["fit", PHOTO, "--landmarks", "mediapipe", "--no-photometric"]


def _cli(*args: object, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "facegeo.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def _paused(at: str, flag: Path, *args: object) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", PAUSED, at, str(flag), *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not flag.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    if not flag.exists():  # pragma: no cover - diagnostics
        proc.kill()
        raise AssertionError(proc.communicate()[1])
    return proc


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _stray(folder: Path) -> list[str]:
    """Temporaries and lock files anywhere under ``folder``."""
    return sorted(p.name for p in folder.rglob("*") if p.name.startswith((TEMP_PREFIX, LOCK_PREFIX)))


def test_a_rerun_keeps_the_users_file(tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run([*FIT, "-o", out], capsys)
    assert code == 0, err
    (out / "keep.txt").write_text("my notes")
    (out / "overlay.png").unlink()  # the user removed one of facegeo's files
    second = _cli(*FIT, "-o", out)
    assert second.returncode == 0, second.stderr
    assert (out / "keep.txt").read_text() == "my notes"
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "fit.json", "keep.txt", "mesh.obj", "overlay.png"]
    assert json.loads((out / MANIFEST).read_text())["files"] == ["fit.json", "mesh.obj", "overlay.png"]
    assert _stray(tmp_path) == []


def test_a_second_run_into_the_same_folder_fails_at_once_naming_the_other(tmp_path, capsys, no_fit):
    out, flag = tmp_path / "out", tmp_path / "flag"
    with StagedOutput(out, replace=True) as stage:  # an earlier output
        stage.path("fit.json").write_text("{}")
    (out / "keep.txt").write_text("my notes")
    before = _files(out)
    running = _paused("photo", flag, *FIT, "-o", out)
    try:
        code, stdout, err = run(["fit", PHOTO, "-o", out], capsys)  # refused before it fits (no_fit)
        assert code == 2 and stdout == ""
        assert_one_line(err, str(out), f"process {running.pid}", "no other facegeo run")
        assert _files(out) == before  # nothing written
        flag.unlink()
        assert running.wait(120) == 0, running.communicate()[1]
    finally:
        if running.poll() is None:  # pragma: no cover
            running.kill()
        running.communicate()
    assert (out / "keep.txt").read_text() == "my notes" and _stray(tmp_path) == []


def test_sigkill_then_a_rerun_leaves_no_staging_folder_and_keeps_the_users_files(tmp_path, capsys):
    out, flag = tmp_path / "out", tmp_path / "flag"
    code, _, err = run([*FIT, "-o", out], capsys)
    assert code == 0, err
    (out / "keep.txt").write_text("my notes")
    before = _files(out)
    killed = _paused("overlay", flag, *FIT, "-o", out)  # its fit.json and mesh.obj are staged
    killed.kill()
    killed.communicate()
    assert _files(out) == before  # the killed run changed nothing in OUT
    assert _stray(tmp_path)  # but left its staging folder and lock file
    code, _, err = run([*FIT, "-o", out], capsys)
    assert code == 0, err
    assert _stray(tmp_path) == [] and (out / "keep.txt").read_text() == "my notes"
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "fit.json", "keep.txt", "mesh.obj", "overlay.png"]


def _texture_sizes(out: Path) -> set[tuple[int, int]]:
    """The sizes of the face's maps in OUT: its PNGs and the textures inside face.glb and face.usdz
    (the eyeballs' own texture, of fixed size, left out)."""
    import io
    import struct
    import zipfile

    images = [p.read_bytes() for p in out.glob("*.png") if p.stem in ("albedo", "normal", "roughness", "specular", "displacement")]
    glb = (out / "face.glb").read_bytes()
    length = struct.unpack("<I", glb[12:16])[0]
    doc, binary = json.loads(glb[20:20 + length]), glb[28 + length:]
    for image in doc["images"]:
        if not image["name"].startswith("eyeballs"):
            view = doc["bufferViews"][image["bufferView"]]
            images.append(binary[view.get("byteOffset", 0):view.get("byteOffset", 0) + view["byteLength"]])
    with zipfile.ZipFile(out / "face.usdz") as usdz:
        images += [usdz.read(n) for n in usdz.namelist() if n.endswith(".png") and "eyeballs" not in n]
    return {Image.open(io.BytesIO(data)).size for data in images}


@pytest.mark.slow
@pytest.mark.parametrize("earlier", [True, False], ids=["into-an-earlier-output", "into-a-new-folder"])
def test_two_reconstructs_at_once_give_one_complete_run_or_a_clean_refusal(tmp_path, capsys, earlier):
    """The battery's case: two ``reconstruct`` runs at once, --size 128 and --size 256, into a
    folder holding an earlier run and the user's file, or into a new folder."""
    out = tmp_path / "out"
    args = ["reconstruct", PHOTO, "-o", out, "--landmarks", "mediapipe", "--no-preview"]
    if earlier:
        code, _, err = run([*args, "--size", "64"], capsys)
        assert code == 0, err
        (out / "keep.txt").write_text("my notes")
    procs = [subprocess.Popen([sys.executable, "-m", "facegeo.cli", *map(str, args), "--size", str(size)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for size in (128, 256)]
    results = [(p.wait(600), *p.communicate()) for p in procs]
    codes = sorted(code for code, _, _ in results)
    assert codes in ([0, 0], [0, 2]), results  # one after the other, or one refused
    for (code, _, err), other in zip(results, reversed(procs)):
        if code == 2:
            assert_one_line(err, str(out), f"process {other.pid}")
    sizes = _texture_sizes(out)
    assert len(sizes) == 1 and sizes <= {(128, 128), (256, 256)}, sizes  # one run's textures, not a mix
    listed = json.loads((out / MANIFEST).read_text())["files"]
    present = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert present == sorted([*listed, MANIFEST, *(["keep.txt"] if earlier else [])])
    assert not earlier or (out / "keep.txt").read_text() == "my notes"
    assert _stray(tmp_path) == []


#: ``facegeo export ...`` paused (FLAG) after its first file is staged.
PAUSED_EXPORT = """
import pathlib, sys, time
import facegeo.export.writers as writers
from facegeo.cli import main
real = writers.export_asset
flag = pathlib.Path(sys.argv[1])
def paused(asset, path, **kwargs):
    written = real(asset, path, **kwargs)
    flag.write_text("staged")
    while flag.exists():
        time.sleep(0.05)
    return written
writers.export_asset = paused
sys.exit(main(sys.argv[2:]))
"""


def test_a_second_export_to_the_same_file_fails_at_once(tmp_path, capsys, asset_dir):
    flag, out = tmp_path / "flag", tmp_path / "out" / "face.glb"
    running = subprocess.Popen([sys.executable, "-c", PAUSED_EXPORT, str(flag), "export", str(asset_dir), "-o", str(out)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not flag.exists() and running.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert flag.exists(), running.communicate()[1]
        code, _, err = run(["export", asset_dir, "-o", out], capsys)
        assert code == 2
        assert_one_line(err, str(out), "output file", f"process {running.pid}")
        code, _, err = run(["export", asset_dir, "-o", out.with_name("other.glb")], capsys)  # another file: not locked
        assert code == 0, err
        flag.unlink()
        assert running.wait(120) == 0, running.communicate()[1]
    finally:
        if running.poll() is None:  # pragma: no cover
            running.kill()
        running.communicate()
    assert sorted(p.name for p in out.parent.iterdir()) == ["face.glb", "other.glb"] and _stray(tmp_path) == []


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
    over = 1.01 * MAX_LANDMARK_ERROR_PERCENT / landmark_error_percent(good)  # every point missed just over the bar
    wrong = dataclasses.replace(good, landmark_errors_px=good.landmark_errors_px * np.float32(over))
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
