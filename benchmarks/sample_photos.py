"""Real face photos for the benchmarks and contact sheets: the bundled one and those packages ship.

:func:`sample_photos` returns paths to: ``assets/photos/astronaut.png`` (the bundled default),
matplotlib's ``sample_data/grace_hopper.jpg`` (a 1950s–80s studio portrait; matplotlib is a
dependency), and scikit-image's ``camera.png`` (the "cameraman": a small greyscale face turned
away, looking down) taken from the scikit-image wheel, which is downloaded once with ``pip
download --no-deps`` into ``~/.cache/facegeo/samples`` (scikit-image itself is not installed).
Photos that cannot be had (no network for the wheel) are left out with a note on stderr.
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

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


def sample_photos() -> list[Path]:
    """Paths of the real face photos available here (the bundled one first)."""
    import matplotlib

    from facegeo.assets import asset_path

    photos = [asset_path("photos/astronaut.png")]
    hopper = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
    if hopper.exists():
        photos.append(hopper)
    return photos + _skimage_photos()
