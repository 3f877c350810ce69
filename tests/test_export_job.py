"""The reconstruction's export begun on the geometry (facegeo.export_job): a forked export writes
the same files as one in this process, a lost child's work is redone with a note, and a failure
on either side leaves nothing. The forks run in fresh interpreters (this test process has torch
imported, where forking is not used by design)."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

from facegeo.assets import asset_path

PHOTO = str(asset_path("photos/astronaut.png"))

BOTH_WAYS = """
import sys
from facegeo.jobs import ReconstructOptions, reconstruct_into_folder
options = ReconstructOptions(size=256)
forked = reconstruct_into_folder({photo!r}, sys.argv[1], options, fork=True)
inline = reconstruct_into_folder({photo!r}, sys.argv[2], options, fork=False)
print(forked.notes == inline.notes, forked.files == inline.files)
"""


def _contents(path: Path) -> dict[str, bytes]:
    """A file's bytes, or a usdz's members' (its zip dates are the writing time's)."""
    if path.suffix == ".usdz":
        with zipfile.ZipFile(path) as archive:
            return {info.filename: archive.read(info) for info in archive.infolist()}
    return {"": path.read_bytes()}


def test_the_forked_export_writes_the_files_the_export_in_this_process_writes(tmp_path):
    forked, inline = tmp_path / "forked", tmp_path / "inline"
    done = subprocess.run([sys.executable, "-c", BOTH_WAYS.format(photo=PHOTO), str(forked), str(inline)],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split() == ["True", "True"]
    files = sorted(p.relative_to(forked) for p in forked.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(inline) for p in inline.rglob("*") if p.is_file())
    assert {Path("face.glb"), Path("face.usdz"), Path("asset.json"), Path("blendshapes.npz"), Path("preview.png")} <= set(files)
    for name in files:
        if name.name in ("fit.json", "asset.json", ".facegeo-output.json"):  # their timings differ
            continue
        assert _contents(forked / name) == _contents(inline / name), name


LOST = """
import os, signal, sys
import facegeo.export_job as export_job
real = export_job._Prepared.__init__
def killed(self, geometry, plan):  # the forked export dies, e.g. by the out-of-memory killer
    if os.getpid() != parent:
        os.kill(os.getpid(), signal.SIGKILL)
    real(self, geometry, plan)
parent = os.getpid()
export_job._Prepared.__init__ = killed
from facegeo.jobs import ReconstructOptions, reconstruct_into_folder
record = reconstruct_into_folder({photo!r}, sys.argv[1], ReconstructOptions(size=256), fork=True)
print([note for note in record.notes if "export" in note])
"""


def test_a_lost_export_child_is_redone_in_the_caller_with_a_note(tmp_path):
    done = subprocess.run([sys.executable, "-c", LOST.format(photo=PHOTO), str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == ("['the forked export ended by signal SIGKILL without an answer; "
                                   "written again in the main process']")
    assert {"face.glb", "face.usdz", "asset.json", "preview.png"} <= {p.name for p in (tmp_path / "out").iterdir()}


FAILS = """
import sys
import facegeo.texturing.default.backend as backend
def broken(self, *args, **kwargs):
    raise MemoryError("the texture stage ran out of memory")
backend.DefaultBackend.inpaint = broken
from facegeo.jobs import ReconstructOptions, reconstruct_into_folder
try:
    reconstruct_into_folder({photo!r}, sys.argv[1], ReconstructOptions(size=256), fork=True)
except MemoryError as error:
    import os
    try:
        os.waitpid(-1, os.WNOHANG)
        print(error, "a child is left")
    except ChildProcessError:
        print(error, "no child is left")
"""


def test_a_texture_stage_failing_while_the_export_child_works_leaves_no_files_and_no_child(tmp_path):
    done = subprocess.run([sys.executable, "-c", FAILS.format(photo=PHOTO), str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == "the texture stage ran out of memory no child is left"
    assert list(tmp_path.iterdir()) == []


def test_scene_geometries_made_before_the_maps_give_the_same_scenes(tmp_path):
    import numpy as np
    import pytest

    import pickle

    from arkit_support import shaped_asset
    from facegeo.errors import InputError
    from facegeo.export.scene import scene_geometries, scene_surfaces
    from facegeo.export.writers import export_scenes, scene_writers
    from test_export_support import synthetic_maps

    asset, *_ = shaped_asset(maps=synthetic_maps(64))
    maps = [m for m in asset.maps if m != "displacement"]
    geometries = scene_geometries(asset, level=1, blendshapes="arkit")
    made = scene_surfaces(asset, level=1, maps=maps, blendshapes="arkit")
    given = scene_surfaces(asset, level=1, maps=maps, blendshapes="arkit", geometries=geometries)
    assert [name for name, _ in made] == [name for name, _ in given] == ["face", *(p.name for p in asset.parts)]
    for (_, a), (_, b) in zip(made, given):
        assert np.array_equal(a.mesh.vertices, b.mesh.vertices) and np.array_equal(a.normals, b.normals)
        assert a.inputs.keys() == b.inputs.keys() and pickle.dumps(a.targets) == pickle.dumps(b.targets)
    # geometry made with other options, or a displacement to bake into it, is refused by name
    with pytest.raises(InputError, match="geometry"):
        scene_surfaces(asset, level=0, maps=maps, blendshapes="arkit", geometries=geometries)
    with pytest.raises(InputError, match="displacement to bake"):
        scene_surfaces(asset, level=1, blendshapes="arkit", geometries=geometries)
    with pytest.raises(InputError, match="geometries"):
        scene_surfaces(asset, level=1, maps=maps, blendshapes="arkit", geometries=geometries[:1])
    # the files written either way are the same
    first, second = tmp_path / "a.glb", tmp_path / "b.glb"
    export_scenes(asset, [(first, None)], level=1, maps=maps)
    [write] = scene_writers(asset, [(second, None)], level=1, maps=maps, geometries=geometries)
    write()
    assert first.read_bytes() == second.read_bytes()


def test_the_export_in_the_caller_uses_the_threads_the_process_may_keep_busy(tmp_path, monkeypatch):
    """A batch worker (one usable thread: its neighbours hold the other cores) writes its files
    and makes its preview one after the other on its own thread; a process that may use two
    spreads them over a pool."""
    import threading

    from arkit_support import shaped_asset
    from facegeo.export_job import ExportJob, ExportPlan
    from test_export_support import synthetic_maps

    asset = shaped_asset(maps=synthetic_maps(64))[0]
    for threads in (1, 2):
        monkeypatch.setattr("facegeo.concurrency.usable_threads", lambda threads=threads: threads)
        folder = tmp_path / str(threads)
        folder.mkdir()
        plan = ExportPlan(folder, ("glb",), "full", 0, False, None)
        ran_on: list[int] = []
        ExportJob(asset, plan, fork=False).complete(asset, [("preview", lambda: ran_on.append(threading.get_ident()))])
        assert (folder / "face.glb").is_file() and (folder / "asset.json").is_file()
        assert (ran_on == [threading.get_ident()]) == (threads == 1), threads
