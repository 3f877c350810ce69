"""The ``facegeo`` command: the demo run and every kind of bad input."""

import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from facegeo import __version__
from facegeo.assets import asset_path
from facegeo.cli import main

PHOTO = asset_path("photos/astronaut.png")


def run(args, capsys):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_version_and_help_from_the_console_script():
    out = subprocess.run([sys.executable, "-m", "facegeo.cli", "--version"], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == f"facegeo {__version__}"
    helped = subprocess.run([sys.executable, "-m", "facegeo.cli", "fit", "--help"], capture_output=True, text=True, check=True)
    assert "--landmarks" in helped.stdout and "--model" in helped.stdout


def test_fit_on_the_bundled_photo(tmp_path, capsys):
    out_dir = tmp_path / "astronaut"
    code, out, err = run(["fit", PHOTO, "-o", out_dir], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out_dir.iterdir()) == [".facegeo-output.json", "fit.json", "mesh.obj", "overlay.png"]
    result = json.loads((out_dir / "fit.json").read_text())
    # the bar: fitted-to-detected landmark RMS ≤ 3 % of the inter-ocular distance
    assert result["info"]["landmark_rms_percent_iod"] <= 3.0
    assert len(result["landmark_errors_px"]) == 88
    assert result["info"]["faces_found"] == 1  # HOG's false face on the glove is not counted
    assert set(result["timings_s"]) >= {"load_model", "detect", "landmarks", "photometric", "total"}
    assert np.asarray(result["gamma"]).shape == (3, 9)
    lines = (out_dir / "mesh.obj").read_text().splitlines()
    assert sum(line.startswith("v ") for line in lines) == 11248
    assert sum(line.startswith("f ") for line in lines) == 22288
    overlay = Image.open(out_dir / "overlay.png")
    assert overlay.size == (512, 512)
    assert "RMS" in out


def test_exif_rotated_photo_is_honoured(tmp_path, capsys):
    image = Image.open(PHOTO).convert("RGB")
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90° clockwise to display": store the pixels turned the other way
    rotated = image.transpose(Image.Transpose.ROTATE_90)
    path = tmp_path / "rotated.jpg"
    rotated.save(path, exif=exif, quality=95)
    code, _, err = run(["fit", path, "-o", tmp_path / "out"], capsys)
    assert code == 0, err
    result = json.loads((tmp_path / "out" / "fit.json").read_text())
    assert abs(result["euler_deg"]["roll"]) < 15  # upright after EXIF, not lying on its side
    assert result["info"]["landmark_rms_percent_iod"] <= 3.0


def test_several_faces_uses_the_largest_and_says_so(tmp_path, capsys):
    face = np.asarray(Image.open(PHOTO).convert("RGB"))[0:280, 90:370]  # the head, 280 x 280
    small = np.asarray(Image.fromarray(face).resize((230, 230)))
    canvas = np.full((280, 512, 3), 128, np.uint8)
    canvas[:, :280] = face
    canvas[25:255, 282:] = small
    path = tmp_path / "two.png"
    Image.fromarray(canvas).save(path)
    code, out, err = run(["fit", path, "-o", tmp_path / "out"], capsys)
    assert code == 0, err
    assert "2 faces found; the largest is used" in out
    result = json.loads((tmp_path / "out" / "fit.json").read_text())
    assert result["info"]["face_box"][2] < 280  # the big face, on the left


@pytest.mark.parametrize(
    "make,expected",
    [
        (lambda p: p.write_text("not a picture"), "a readable PNG/JPEG"),
        (lambda p: p.write_bytes(b""), "empty"),
        (lambda p: Image.new("RGB", (1, 1)).save(p, format="PNG"), "1x1"),
        (lambda p: Image.new("RGB", (256, 256), (120, 120, 120)).save(p, format="PNG"), "no face"),
    ],
    ids=["text", "empty", "1x1", "no-face"],
)
def test_bad_photos_fail_cleanly(tmp_path, capsys, make, expected):
    path = tmp_path / "photo.png"
    make(path)
    out_dir = tmp_path / "out"
    code, _, err = run(["fit", path, "-o", out_dir], capsys)
    assert code == 2
    assert str(path) in err and expected in err
    assert "Traceback" not in err and err.count("\n") == 1
    assert not out_dir.exists()
    assert not list(tmp_path.glob(".facegeo-tmp-*"))


def test_missing_photo_and_bad_model_fail_cleanly(tmp_path, capsys):
    code, _, err = run(["fit", tmp_path / "missing.jpg", "-o", tmp_path / "out"], capsys)
    assert code == 2 and "missing.jpg" in err
    bad_model = tmp_path / "model.npz"
    np.savez(bad_model, mean_shape=np.zeros((3, 3)))
    code, _, err = run(["fit", PHOTO, "-o", tmp_path / "out", "--model", bad_model], capsys)
    assert code == 2 and "model.npz" in err
    assert not (tmp_path / "out").exists()


def test_face_cut_by_the_border(tmp_path, capsys):
    image = np.asarray(Image.open(PHOTO).convert("RGB"))
    path = tmp_path / "cut.png"
    Image.fromarray(np.ascontiguousarray(image[:, 215:])).save(path)  # left third of the face cut off
    code, _, err = run(["fit", path, "-o", tmp_path / "out"], capsys)
    if code == 0:
        result = json.loads((tmp_path / "out" / "fit.json").read_text())
        assert np.all(np.isfinite(result["landmark_errors_px"]))
    else:
        assert code == 2 and "cut.png" in err and "Traceback" not in err
