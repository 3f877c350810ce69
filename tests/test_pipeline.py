"""The whole pipeline on the bundled photo at a small map size."""

import json

import numpy as np
import pytest
from PIL import Image

from facegeo import load_model, load_photo
from facegeo.assets import asset_path
from facegeo.cli import main
from facegeo.errors import InputError
from facegeo.pipeline import STAGES, reconstruct, reconstruct_with_fit
from facegeo.texturing.default import DEFAULT_SETTINGS
from facegeo.texturing.preview import relit_preview

PHOTO = asset_path("photos/astronaut.png")


@pytest.fixture(scope="module")
def small_asset():
    photo = load_photo(PHOTO)
    model = load_model()
    asset, fit = reconstruct_with_fit(photo, model, size=256, upscale=2, maps={"albedo", "normal", "displacement"})
    return photo, model, asset, fit


def test_only_the_requested_maps_are_made(small_asset):
    _, _, asset, fit = small_asset
    assert set(asset.maps) == {"albedo", "normal", "displacement"}
    assert set(asset.constants) == {"roughness", "specular"}
    assert asset.maps["albedo"].shape == (512, 512, 3)  # 256 upscaled ×2
    np.testing.assert_allclose(np.linalg.norm(asset.maps["normal"], axis=-1), 1.0, atol=1e-4)
    assert set(asset.metadata["timings_s"]) == set(STAGES)
    np.testing.assert_allclose(asset.metadata["fit"]["alpha"], fit.alpha)
    assert 0.0 <= asset.maps["albedo"].min() and asset.maps["albedo"].max() <= 1.0
    report = asset.metadata["texture_report"]
    assert report["homogenise"]["remaining_fraction"] < 0.5
    level = report["albedo_level"]  # the albedo's level and what set it (fit.json's texture_report)
    assert "skin_prior" in level["used"] and level["k"] > 0
    assert DEFAULT_SETTINGS.level_skin_range[0] <= level["skin_luminance"] <= DEFAULT_SETTINGS.level_skin_range[1]
    mask = asset.metadata["skin_mask"]  # hair, suit and background are out of M_vis
    assert mask["source"] == "mediapipe" and 0.5 < mask["occluded_fraction"] < 0.98


def test_albedo_is_skin_coloured_on_the_cheeks(small_asset):
    _, model, asset, _ = small_asset
    from facegeo.skin_mask import vertex_regions
    from facegeo.uv import rasterize_uv

    raster = rasterize_uv(model, size=512)
    cheeks = raster.scatter(raster.interpolate(vertex_regions(model)["cheeks"][model.triangles][..., None]))[..., 0] > 0.5
    r, g, b = asset.maps["albedo"][cheeks].mean(axis=0)
    assert r > g > b and 0.3 < r < 0.95  # reddish skin, neither black nor blown out


def test_the_asset_carries_the_parts_with_the_photos_iris_colour(small_asset):
    _, _, asset, _ = small_asset
    assert [p.name for p in asset.parts] == ["eyeballs", "eye_sockets", "mouth_socket", "gums_tongue", "teeth"]
    report = asset.metadata["parts"]
    assert len(report["irises"]) == 2 and "note" not in report
    r, g, b = report["iris_srgb_used"]
    assert r > g > b and r < 0.6  # the astronaut's brown eyes
    eyeballs = asset.parts[0]
    assert eyeballs.maps["albedo"].shape == (256, 256, 3) and set(eyeballs.constants) == {"roughness", "specular"}
    assert asset.face_triangles is not None and 0.5 < asset.face_triangles.mean() < 1.0


def test_preview_panels(small_asset):
    photo, model, asset, fit = small_asset
    p = 64
    preview = relit_preview(photo.image, asset, fit, panel=p)
    assert preview.shape == (2 * p, 5 * p, 3) and preview.dtype == np.uint8
    views = preview[:, 2 * p:].astype(np.float32)
    textured, clay = views[:p], views[p:]
    background = np.all(np.abs(views - round(0.12 * 255)) <= 1, axis=-1)
    for k in range(3):  # every view shows the head, neither empty nor overflowing
        covered = 1.0 - background[:, k * p:(k + 1) * p].mean()
        assert 0.15 < covered < 0.9
    clay_pixels = clay[~background[p:]]
    assert np.abs(clay_pixels[:, 0] - clay_pixels[:, 2]).max() <= 2  # clay is grey
    textured_pixels = textured[~background[:p]]
    assert np.mean(textured_pixels[:, 0] - textured_pixels[:, 2]) > 10  # skin is not
    # the photo panel is the photo around the face (not the rendering)
    assert np.abs(preview[:, :2 * p].astype(float).mean() - photo.image.mean()) < 40


def test_the_preview_in_two_halves_is_the_preview(small_asset):
    # facegeo reconstruct rasterises the views on the geometry (no skin maps yet) and shades them
    # once the maps exist: the same pixels as relit_preview, whichever skin maps it expected
    import dataclasses

    from facegeo.landmarks.scheme import IBUG68
    from facegeo.texturing.preview import PreviewViews

    photo, _, asset, fit = small_asset
    whole = relit_preview(photo.image, asset, fit, panel=64)
    geometry = dataclasses.replace(asset, maps={}, constants={}, metadata={})
    for expected in (frozenset(asset.maps), frozenset()):  # right, and wrong (no normal map: other tangents)
        views = PreviewViews(geometry, photo.image, fit.landmarks[IBUG68], panel=64, skin_maps=expected)
        np.testing.assert_array_equal(views.render(asset), whole)


def test_bad_arguments_raise():
    with pytest.raises(InputError, match="maps"):
        reconstruct(np.zeros((64, 64, 3), np.uint8), maps={"sheen"})
    with pytest.raises(InputError, match="upscale"):
        reconstruct(np.zeros((64, 64, 3), np.uint8), upscale=3)


def test_reconstruct_command(tmp_path, capsys):
    out = tmp_path / "rec"
    code = main(["reconstruct", str(PHOTO), "-o", str(out), "--size", "256", "--format", "glb,usda", "--maps", "albedo,normal,roughness"])
    _, err = capsys.readouterr()
    assert code == 0, err
    names = {p.name for p in out.iterdir()}
    assert {"fit.json", "asset.json", "mesh.obj", "albedo.png", "normal.png", "roughness.png", "face.glb", "face.usda", "preview.png"} <= names
    assert "specular.png" not in names and "displacement.png" not in names
    record = json.loads((out / "fit.json").read_text())
    assert {"fit", "unwrap", "export", "preview", "total"} <= set(record["timings_s"]["stages"])
    assert Image.open(out / "albedo.png").size == (256, 256)
    import pygltflib

    doc = pygltflib.GLTF2().load_binary(str(out / "face.glb"))  # --parts full, the default
    assert [m.name for m in doc.meshes] == ["face", "eyeballs", "eye_sockets", "mouth_socket", "gums_tongue", "teeth"]
    assert (out / "parts" / "eyeballs_albedo.png").is_file()
    assert Image.open(out / "preview.png").size == (5 * 256, 2 * 256)


def test_reconstruct_command_bad_maps_leaves_nothing(tmp_path, capsys):
    out = tmp_path / "rec"
    code = main(["reconstruct", str(PHOTO), "-o", str(out), "--maps", "albedo,sheen"])
    _, err = capsys.readouterr()
    assert code == 2 and "--maps" in err and not out.exists()


# ------------------------------------------------------------------------------------- the seams
def test_the_pipeline_fits_with_any_fitter(small_asset):
    """``fitter=``: a callable photo -> Fit (facegeo.fitting.Fitter) is called once, with the
    keywords the protocol names, and its Fit is the one the asset is built on."""
    photo, model, _, known = small_asset
    calls = []

    def fitter(image, model=None, landmarks=None, detector="hybrid", camera=None, photometric=True):
        calls.append({"image": image, "model": model, "landmarks": landmarks, "detector": detector, "camera": camera})
        return known

    asset, result = reconstruct_with_fit(photo, model, fitter=fitter, size=64, maps={"albedo"}, detector="mediapipe", parts=False)
    assert result is known and len(calls) == 1
    assert calls[0] == {"image": photo, "model": model, "landmarks": None, "detector": "mediapipe", "camera": None}
    np.testing.assert_array_equal(asset.vertices, known.shape_vertices)
    np.testing.assert_allclose(asset.metadata["fit"]["alpha"], known.alpha)


def test_the_unwrap_leaves_the_cores_that_geometry_readys_work_keeps_busy(monkeypatch, small_asset):
    """``geometry_ready`` returns the cores its work keeps busy (the export's forked child): the
    unwrap's two halves then run on that many threads fewer, with the same maps."""
    import facegeo.pipeline as pipeline

    photo, model, _, known = small_asset
    counts = []
    run = pipeline.run_concurrently
    monkeypatch.setattr(pipeline, "usable_threads", lambda: 2)
    monkeypatch.setattr(pipeline, "run_concurrently", lambda tasks, workers=2: counts.append(workers) or run(tasks, workers))
    made = [reconstruct_with_fit(photo, model, fitter=lambda image, **_: known, size=64, maps={"albedo"}, parts=False,
                                 geometry_ready=lambda geometry, busy=busy: busy)[0] for busy in (None, 1)]
    assert counts == [2, 1]
    np.testing.assert_array_equal(made[0].maps["albedo"], made[1].maps["albedo"])


def test_a_second_backend_needs_only_the_protocol(small_asset):
    """What the pipeline reads of a backend is what TextureBackend declares: the four stages,
    ``name``, ``report`` (-> texture_report) and ``constants`` (-> the maps not computed)."""
    from facegeo.texturing.backend import SKIN_CONSTANTS, TextureBackend
    from facegeo.texturing.default import DefaultBackend

    class Flat:  # no base class, nothing private: a grey albedo, nothing else
        name = "flat"
        constants = {"roughness": 0.3, "specular": 0.7}

        def __init__(self):
            self.report = {}

        def inpaint(self, T_inc, M_vis, ctx):
            self.report["inpaint"] = {"texels": int(ctx.coverage.sum())}
            return np.full_like(T_inc, 0.5)

        def homogenise(self, T_full, ctx):
            return T_full

        def materials(self, T_hom, ctx, maps=frozenset()):
            return {"albedo": T_hom} if "albedo" in maps else {}

        def upscale(self, map_, factor):
            return np.repeat(np.repeat(map_, factor, axis=0), factor, axis=1)

    assert isinstance(Flat(), TextureBackend) and isinstance(DefaultBackend(), TextureBackend)
    assert DefaultBackend().constants == SKIN_CONSTANTS
    no_constants = type("NoConstants", (), {k: v for k, v in vars(Flat).items() if k != "constants"})()
    assert not isinstance(no_constants, TextureBackend)  # the protocol declares them: a backend must say
    photo, model, _, known = small_asset
    backend = Flat()
    asset, _ = reconstruct_with_fit(photo, model, backend=backend, fitter=lambda image, **_: known, size=64, upscale=2,
                                    maps={"albedo", "normal"}, parts=False)
    assert asset.metadata["backend"] == "flat"
    assert set(asset.metadata["texture_report"]) == {"inpaint"} and asset.metadata["texture_report"]["inpaint"]["texels"] > 0
    assert asset.constants == {"roughness": 0.3, "specular": 0.7} and set(asset.maps) == {"albedo"}
    assert asset.maps["albedo"].shape == (128, 128, 3) and np.all(asset.maps["albedo"] == 0.5)


# ------------------------------------------------------------------ the export stage's two workers
@pytest.fixture
def fitted_job(monkeypatch, small_asset):
    """reconstruct_into_folder with the pipeline's result given (the module's small asset)."""
    from dataclasses import replace

    _, _, asset, fit = small_asset

    def reconstructed(*args, geometry_ready=None, **kwargs):
        if geometry_ready is not None:  # as the pipeline does before its texture stages
            geometry_ready(replace(asset, maps={}, constants={}, metadata={}))
        return asset, fit

    monkeypatch.setattr("facegeo.pipeline.reconstruct_with_fit", reconstructed)


def _written(folder) -> dict[str, bytes]:
    """Every file under ``folder`` (fit.json without its timings; a usdz's members, its zip
    entries carrying their time)."""
    import io
    import zipfile

    out = {}
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        rel = path.relative_to(folder).as_posix()
        if rel == "fit.json":
            record = json.loads(path.read_text())
            del record["timings_s"]
            out[rel] = json.dumps(record).encode()
        elif rel.endswith(".usdz"):
            with zipfile.ZipFile(io.BytesIO(path.read_bytes())) as package:
                out.update({f"{rel}/{name}": package.read(name) for name in package.namelist()})
        else:
            out[rel] = path.read_bytes()
    return out


def test_two_export_workers_write_what_one_writes(tmp_path, monkeypatch, fitted_job):
    from facegeo.jobs import ReconstructOptions, reconstruct_into_folder

    options = ReconstructOptions(formats=("usdz", "glb", "usda"))
    monkeypatch.setattr("facegeo.concurrency.usable_threads", lambda: 2)  # whatever an earlier test left torch's pool at
    reconstruct_into_folder(PHOTO, tmp_path / "two", options)
    monkeypatch.setattr("facegeo.concurrency.EXPORT_WORKERS", 1)
    record = reconstruct_into_folder(PHOTO, tmp_path / "one", options)
    two, one = _written(tmp_path / "two"), _written(tmp_path / "one")
    assert two.keys() == one.keys() and all(two[k] == one[k] for k in one), [k for k in one if two.get(k) != one[k]]
    assert {"face.usdz/face.usdc", "face.glb", "face.usda", "face_textures/albedo.png", "albedo.png", "preview.png"} <= one.keys()
    assert {"export", "preview", "total"} <= set(record.timings)


def test_a_failing_export_task_rolls_back_after_the_others_finish(tmp_path, monkeypatch, fitted_job):
    import facegeo.export.asset_io as asset_io
    from facegeo.jobs import reconstruct_into_folder

    def broken(*args, **kwargs):
        raise InputError("<asset>", "metadata", "something writable", "a broken writer")

    monkeypatch.setattr(asset_io, "write_asset_files", broken)
    with pytest.raises(InputError, match="a broken writer"):
        reconstruct_into_folder(PHOTO, tmp_path / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no folder, no temporaries, no lock file


@pytest.mark.parametrize("signum", ["SIGINT", "SIGTERM"])
def test_a_signal_during_the_export_leaves_nothing(tmp_path, capsys, monkeypatch, fitted_job, signum):
    """The facegeo command turns the signal into an exception in the main thread, which waits for
    the two export workers: the folder is rolled back once the one still writing is done."""
    import os
    import signal
    import time

    import facegeo.export.asset_io as asset_io

    real = asset_io.write_asset_files
    finished = []

    def write_then_signal(asset, folder, **kwargs):
        doc = real(asset, folder, **kwargs)
        os.kill(os.getpid(), getattr(signal, signum))  # handled in the main thread, not this worker
        time.sleep(0.5)
        (folder / "late.txt").write_text("still writing after the signal")
        finished.append(True)
        return doc

    monkeypatch.setattr(asset_io, "write_asset_files", write_then_signal)
    monkeypatch.setattr("facegeo.forked_call.can_fork", lambda: False)  # the export's threads in this process (the forked export: test_forked_call)
    monkeypatch.setattr("facegeo.concurrency.usable_threads", lambda: 2)  # two of them, whatever an earlier test left torch's pool at
    code = main(["reconstruct", str(PHOTO), "-o", str(tmp_path / "out")])
    _, err = capsys.readouterr()
    assert code == 128 + getattr(signal, signum) and "interrupted" in err and err.count("\n") == 1
    assert finished == [True]
    time.sleep(0.2)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_clip_preview_draws_the_posed_asset_over_each_frame(small_asset):
    from facegeo.texturing.preview import clip_preview, posed_asset

    photo, model, asset, fit = small_asset
    names = list(model.expression_names)
    fitted = dict(zip(names, np.asarray(fit.delta, float)))
    same = posed_asset(asset, fitted)  # at the fitted weights: the asset as it is
    np.testing.assert_allclose(same.vertices, asset.vertices, atol=1e-3)
    for a, b in zip(same.parts, asset.parts):
        np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-3)
    jaw = posed_asset(asset, {**fitted, "jawOpen": 0.8})
    chin = model.landmark_indices[8]
    assert jaw.vertices[chin, 1] < asset.vertices[chin, 1] - 5.0  # the jaw opens: the chin drops (mm)
    p = 64
    frames = [(photo.image, fit.rotation, fit.translation, weights, fit.landmarks[:68]) for weights in (fitted, {**fitted, "jawOpen": 0.8})]
    preview = clip_preview(frames, asset, fit.camera, panel=p)
    assert preview.shape == (3 * p, 2 * p, 3) and preview.dtype == np.uint8
    frame, textured, clay = (preview[k * p:(k + 1) * p, :p].astype(float) for k in range(3))
    drawn = np.any(np.abs(textured - frame) > 8, axis=-1)  # where the asset covers the frame
    assert 0.3 < drawn.mean() < 0.98
    ys, xs = np.nonzero(drawn)
    assert abs(xs.mean() - p / 2) < 0.12 * p  # drawn over the face, which the panel centres
    centre = clay[p // 2 - 4:p // 2 + 4, p // 2 - 4:p // 2 + 4].reshape(-1, 3)
    assert np.abs(centre[:, 0] - centre[:, 2]).max() <= 2  # grey clay
    assert np.abs(textured[p // 2, p // 2] - frame[p // 2, p // 2]).max() < 80  # the texture is the face's colour
    second = preview[2 * p:, p:].astype(float)
    assert np.abs(second - clay).mean() > 1.0  # the open jaw shows


def test_a_photo_with_a_hand_over_the_face_is_not_the_reference():
    import dataclasses

    from facegeo import fit
    from facegeo.pipeline import reconstruct_views
    from facegeo.skin_mask import skin_mask

    photo = load_photo(PHOTO)
    mirrored = np.ascontiguousarray(photo.image[:, ::-1])
    model = load_model()
    fits = [fit(photo, model, photometric=False), fit(mirrored, model, photometric=False)]
    masks = [skin_mask(photo.image, fits[0].landmarks), skin_mask(mirrored, fits[1].landmarks)]
    _, frontal, _ = reconstruct_views([photo, mirrored], fits, model, size=64, maps={"albedo"}, skins=masks, parts=False)
    with_hand = list(masks)
    with_hand[frontal] = dataclasses.replace(masks[frontal], hands=1)
    _, reference, _ = reconstruct_views([photo, mirrored], fits, model, size=64, maps={"albedo"}, skins=with_hand, parts=False)
    assert reference == 1 - frontal  # the other, though it faces the camera less
    both = [dataclasses.replace(m, hands=1) for m in masks]  # a hand in every photo: the most frontal again
    assert reconstruct_views([photo, mirrored], fits, model, size=64, maps={"albedo"}, skins=both, parts=False)[1] == frontal
