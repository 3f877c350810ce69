"""``facegeo track`` on real videos of real faces, and on each clip mirrored left-right.

The clips are CC BY 2.0 selfie videos by Aaron "tango" Tang that OpenMPF ships as test data
(github.com/openmpf/openmpf; the licence and the author are stated in the ``NOTICE`` file next to
each video: ``trunk/mpf-system-tests/src/test/resources/samples/face/NOTICE`` for
``video_01.mp4``, ``trunk/workflow-manager/src/test/resources/samples/NOTICE`` for
``new_face_video-90.mp4``). They are not in this repository: the script fetches them from a pinned
commit, checks their sha256 and caches them in ``~/.cache/facegeo/clips`` (``--cache DIR``). Without
network, put the files (same names, same sha256) in the cache yourself, e.g. from a clone of
openmpf: ``git -C openmpf show COMMIT:PATH > ~/.cache/facegeo/clips/NAME``.

Attribution (CC BY 2.0, https://creativecommons.org/licenses/by/2.0/):
  * ``video_01.mp4``: © 2012 Aaron "tango" Tang, https://www.flickr.com/photos/hahatango/7484510910
  * ``new_face_video-90.mp4``: © 2012 Aaron "tango" Tang, https://www.flickr.com/photos/hahatango/7484448042
    (OpenMPF: "Rotated 90 degrees": the rotation is container metadata, which OpenCV applies).

For each clip (a time range of a source video) it runs ``facegeo track SRC --start --end -o OUT``,
then writes the same frames (decoded by :func:`facegeo.video.open_video`) mirrored left-right into
a lossless FFV1 .avi with OpenCV, runs ``facegeo track`` on that, and reports per clip: frames,
frames with a face, frames/s, and the mirror check of issue 48: the mirrored clip gives the same
curves with Left and Right swapped (median absolute difference <= 0.08 over the curves that move,
i.e. weights whose range over the clip is >= 0.1) and head yaw correlated >= 0.9 with its negation.
A markdown table goes to stdout; ``--strip`` (default ``docs/track_real_clips.jpg``) is a contact
strip: 8 evenly spaced frames per clip, the face crop beside the same crop with the tracked mesh's
88 landmark vertices (identity from track.json's alpha, the frame's delta, R, t and camera) and the
head's axes drawn, with yaw/pitch/roll and the 3 largest ARKit weights of take.csv underneath.

    python benchmarks/track_real_clips.py [--work /tmp/track_real_clips] [--clips a,b] [--no-mirror]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
COMMIT = "1f9b0dde560a6b284fb71e7cfb441b355ca9e404"  # openmpf/openmpf, 2026-04-28
RAW = "https://raw.githubusercontent.com/openmpf/openmpf/{commit}/{path}"

SOURCES = {
    "video_01.mp4": {
        "path": "trunk/mpf-system-tests/src/test/resources/samples/face/video_01.mp4",
        "notice": "trunk/mpf-system-tests/src/test/resources/samples/face/NOTICE",
        "sha256": "5eacf0a11d51413300ee0f4719b7ac7b52b47310a49320703c1d2639ebbc9fea",
        "bytes": 351768,
        "licence": "CC BY 2.0, (c) 2012 Aaron \"tango\" Tang, flickr.com/photos/hahatango/7484510910",
    },
    "new_face_video-90.mp4": {
        "path": "trunk/workflow-manager/src/test/resources/samples/new_face_video-90.mp4",
        "notice": "trunk/workflow-manager/src/test/resources/samples/NOTICE",
        "sha256": "c059a6fe6d6340bebc20eb8f2803317b6c9b57e7fcec60f4e352062a7b800be4",
        "bytes": 2714086,
        "licence": "CC BY 2.0, (c) 2012 Aaron \"tango\" Tang, flickr.com/photos/hahatango/7484448042",
    },
}

#: name -> (source, start s, end s, what it shows). Ranges keep one person in view (the selfie
#: video changes hands: a second person at 2.5-3.8 s and 8-8.8 s, landscape from 11.3 s).
CLIPS = {
    "event": ("video_01.mp4", None, None, "woman at a reception (face ~50 px wide), a man passes close to the camera"),
    "selfie_a": ("new_face_video-90.mp4", 0.0, 2.4, "helmet + glasses, smile; the camera passes to a second person at ~1.6 s"),
    "selfie_b": ("new_face_video-90.mp4", 5.0, 7.4, "helmet + glasses, hand over the face, smile; the second person at 7.4 s"),
}

MAD_LIMIT, YAW_CORR_LIMIT, MOVING_RANGE = 0.08, 0.9, 0.1


def fetch(name: str, cache: Path) -> Path:
    """The cached source (downloaded from the pinned commit when absent), sha256-checked."""
    spec = SOURCES[name]
    target = cache / name
    if not target.exists():
        cache.mkdir(parents=True, exist_ok=True)
        url = RAW.format(commit=COMMIT, path=spec["path"])
        print(f"fetching {url}", file=sys.stderr)
        tmp = target.with_suffix(".part")
        try:
            with urllib.request.urlopen(url, timeout=60) as response, open(tmp, "wb") as out:
                shutil.copyfileobj(response, out)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            sys.exit(f"{name}: cannot download {url} ({exc}); put the file (sha256 {spec['sha256']}) in {cache}")
        tmp.replace(target)
    digest = hashlib.sha256(target.read_bytes()).hexdigest()
    if digest != spec["sha256"]:
        sys.exit(f"{target}: sha256 {digest}, expected {spec['sha256']}; delete it to fetch again")
    return target


def track(video: Path, out: Path, start: float | None, end: float | None) -> dict:
    if out.exists():
        shutil.rmtree(out)
    exe = Path(sys.executable).with_name("facegeo")
    cmd = [str(exe) if exe.exists() else "facegeo", "track", str(video), "-o", str(out)]
    if start is not None:
        cmd += ["--start", str(start)]
    if end is not None:
        cmd += ["--end", str(end)]
    print("$ facegeo " + " ".join(cmd[1:]), file=sys.stderr)
    subprocess.run(cmd, check=True, cwd=REPO_ROOT, stdout=subprocess.DEVNULL)
    return json.loads((out / "track.json").read_text())


def write_mirrored(video: Path, start: float | None, end: float | None, target: Path) -> int:
    """The frames ``facegeo track`` reads, flipped left-right, into a lossless FFV1 .avi."""
    import cv2

    from facegeo.video import open_video

    info, frames = open_video(video, start, end)
    writer = None
    n = 0
    for frame in frames:
        bgr = cv2.cvtColor(frame.image[:, ::-1], cv2.COLOR_RGB2BGR)
        if writer is None:
            writer = cv2.VideoWriter(str(target), cv2.VideoWriter_fourcc(*"FFV1"), info.fps, (bgr.shape[1], bgr.shape[0]))
            if not writer.isOpened():
                sys.exit(f"OpenCV cannot write FFV1 to {target}")
        writer.write(np.ascontiguousarray(bgr))
        n += 1
    writer.release()
    return n


def swapped(name: str) -> str:
    return name.replace("Left", "\0").replace("Right", "Left").replace("\0", "Right")


def mirror_check(plain: Path, mirror: Path, rec: dict, rec_m: dict) -> dict:
    from facegeo.export.live_link import ARKIT_NAMES, read_live_link_csv

    a = read_live_link_csv(plain / "take.csv", fps=rec["fps"])
    b = read_live_link_csv(mirror / "take.csv", fps=rec_m["fps"])
    n = min(a.n_frames, b.n_frames)
    both = np.array([fa["found"] and fb["found"] for fa, fb in zip(rec["frames"][:n], rec_m["frames"][:n])])
    wa = a.weights[:n][both]
    wb = b.weights[:n][both][:, [ARKIT_NAMES.index(swapped(k)) for k in ARKIT_NAMES]]  # b's Right as a's Left
    moving = [k for k in range(len(ARKIT_NAMES)) if np.ptp(wa[:, k]) >= MOVING_RANGE or np.ptp(wb[:, k]) >= MOVING_RANGE]
    diff = np.abs(wa[:, moving] - wb[:, moving])
    per_curve = np.median(diff, axis=0) if moving else np.zeros(0)
    worst = [(ARKIT_NAMES[moving[k]], float(per_curve[k])) for k in np.argsort(-per_curve)[:3]]
    ya, yb = a.rotations["head"][:n][both, 0], b.rotations["head"][:n][both, 0]
    ra, rb = a.rotations["head"][:n][both, 2], b.rotations["head"][:n][both, 2]
    corr = lambda x, y: float(np.corrcoef(x, y)[0, 1]) if np.std(x) > 0 and np.std(y) > 0 else float("nan")  # noqa: E731
    mad = float(np.median(diff)) if moving else 0.0
    yaw_corr = corr(ya, -yb)
    return {"frames_compared": int(both.sum()), "moving": len(moving), "mad": mad, "worst": worst,
            "yaw_corr": yaw_corr, "roll_corr": corr(ra, -rb), "yaw_range_deg": float(np.degrees(np.ptp(ya))),
            "yaw_mean_abs_sum_deg": float(np.degrees(np.median(np.abs(ya + yb)))),
            "pass": bool(mad <= MAD_LIMIT and yaw_corr >= YAW_CORR_LIMIT)}


def contact_rows(name: str, video: Path, start, end, out: Path, rec: dict, model, tile: int = 200) -> np.ndarray:
    """Two rows of 4 (crop | crop with the tracked landmarks and axes) pairs for 8 frames."""
    import cv2

    from facegeo.camera import Camera, project
    from facegeo.export.live_link import ARKIT_NAMES, read_live_link_csv
    from facegeo.video import open_video

    take = read_live_link_csv(out / "take.csv", fps=rec["fps"])
    camera = Camera(**rec["camera"])
    alpha = np.asarray(rec["alpha"], np.float32)
    n = len(rec["frames"])
    picks = set(np.linspace(0, n - 1, 8).round().astype(int).tolist())
    _, frames = open_video(video, start, end)
    pairs = []
    for k, frame in enumerate(frames):
        if k not in picks:
            continue
        f = rec["frames"][k]
        img = frame.image
        h, w = img.shape[:2]
        pts = axes = None
        if f["found"]:
            R, t = np.asarray(f["rotation"]), np.asarray(f["translation_mm"])
            lm3 = model.shape_numpy(alpha, np.asarray(f["delta"], np.float32), model.landmark_indices)
            pts = project(lm3.astype(np.float64), R, t, camera) - 0.5
            centre = lm3.mean(axis=0)
            axes = project(centre + np.vstack([np.zeros(3), 60 * np.eye(3)]), R, t, camera) - 0.5
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            c, half = (lo + hi) / 2, max(hi - lo) * 0.95
        else:
            c, half = np.array([w / 2, h / 2]), min(w, h) / 2
        x0, y0 = int(round(c[0] - half)), int(round(c[1] - half))
        size = max(int(round(2 * half)), 8)
        pad = size
        padded = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=(0, 0, 0))
        crop = padded[y0 + pad:y0 + pad + size, x0 + pad:x0 + pad + size]
        s = tile / size
        left = cv2.resize(crop, (tile, tile), interpolation=cv2.INTER_AREA)
        right = left.copy()
        if pts is not None:
            to = lambda p: (int(round((p[0] - x0) * s * 16)), int(round((p[1] - y0) * s * 16)))  # noqa: E731
            for p in pts:
                cv2.circle(right, to(p), 2 * 16, (255, 60, 60), -1, cv2.LINE_AA, 4)
            for j, col in enumerate([(255, 0, 0), (0, 200, 0), (0, 120, 255)]):
                cv2.line(right, to(axes[0]), to(axes[j + 1]), col, 2, cv2.LINE_AA, 4)
        band = np.full((46, 2 * tile, 3), 255, np.uint8)
        e = f.get("euler_deg") or {}
        top = np.argsort(-take.weights[k])[:3]
        line1 = (f"{name} #{f['index']} t={f['time_s']:.1f}s " +
                 (f"yaw {e['yaw']:+.0f} pitch {e['pitch']:+.0f} roll {e['roll']:+.0f}" if f["found"] else "NO FACE"))
        line2 = "  ".join(f"{ARKIT_NAMES[j]} {take.weights[k, j]:.2f}" for j in top)
        cv2.putText(band, line1, (4, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(band, line2, (4, 38), cv2.FONT_HERSHEY_SIMPLEX, 0.40, (0, 0, 150), 1, cv2.LINE_AA)
        pair = np.vstack([np.hstack([left, right]), band])
        pairs.append(np.pad(pair, ((0, 6), (0, 8), (0, 0)), constant_values=255))
    while len(pairs) < 8:
        pairs.append(np.full_like(pairs[0], 255))
    return np.vstack([np.hstack(pairs[:4]), np.hstack(pairs[4:8])])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "facegeo" / "clips")
    ap.add_argument("--work", type=Path, default=Path("/tmp/track_real_clips"))
    ap.add_argument("--clips", default=",".join(CLIPS), help=f"comma-separated, of {', '.join(CLIPS)}")
    ap.add_argument("--no-mirror", action="store_true")
    ap.add_argument("--strip", type=Path, default=REPO_ROOT / "docs" / "track_real_clips.jpg")
    ap.add_argument("--reuse", action="store_true", help="reuse existing track outputs in --work")
    args = ap.parse_args()
    import cv2

    import facegeo

    model = facegeo.load_model()
    rows, strips = [], []
    for name in args.clips.split(","):
        source, start, end, what = CLIPS[name]
        video = fetch(source, args.cache)
        work = args.work / name
        work.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        rec = (json.loads((work / "plain" / "track.json").read_text()) if args.reuse and (work / "plain" / "track.json").exists()
               else track(video, work / "plain", start, end))
        wall = time.perf_counter() - t0
        row = {"clip": name, "source": source, "range": f"{start or 0:g}-{end if end is not None else 'end'} s",
               "frames": rec["frames_tracked"], "found": rec["frames_with_face"], "fps": rec["frames_per_second"],
               "wall": wall, "rms": float(np.median([f["landmark_rms_percent_iod"] for f in rec["frames"] if f["found"]])),
               "yaw": [f["euler_deg"]["yaw"] for f in rec["frames"] if f["found"]]}
        if not args.no_mirror:
            mirrored = work / "mirrored.avi"
            if not (args.reuse and (work / "mirror" / "track.json").exists()):
                write_mirrored(video, start, end, mirrored)
                rec_m = track(mirrored, work / "mirror", None, None)
            else:
                rec_m = json.loads((work / "mirror" / "track.json").read_text())
            row["mirror"] = mirror_check(work / "plain", work / "mirror", rec, rec_m)
            row["found_m"] = rec_m["frames_with_face"]
        rows.append(row)
        strips.append(contact_rows(name, video, start, end, work / "plain", rec, model))
        print(json.dumps({k: v for k, v in row.items() if k != "yaw"}), file=sys.stderr)

    print("| clip | source, range | frames | with a face (mirrored) | frames/s | landmark RMS % IOD (median) | yaw range ° (take) "
          "| curves that move | median abs diff (≤ 0.08) | worst curves | yaw corr with −mirror (≥ 0.9) | roll corr | mirror check |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        m = r.get("mirror")
        yaw_range = m["yaw_range_deg"] if m else (np.ptp(r["yaw"]) if r["yaw"] else float("nan"))
        if m:
            worst = ", ".join(f"{n} {v:.2f}" for n, v in m["worst"])
            tail = (f"{m['moving']} | {m['mad']:.3f} | {worst} | {m['yaw_corr']:.3f} | {m['roll_corr']:.3f} | "
                    f"{'pass' if m['pass'] else 'FAIL'} |")
            found = f"{r['found']} ({r['found_m']})"
        else:
            tail, found = "– | – | – | – | – | – |", str(r["found"])
        print(f"| {r['clip']} | {r['source']} {r['range']} | {r['frames']} | {found} | {r['fps']:.1f} | {r['rms']:.1f} | "
              f"{yaw_range:.0f} | " + tail)

    if strips and args.strip:
        width = max(s.shape[1] for s in strips)
        sheet = np.vstack([np.pad(s, ((0, 10), (0, width - s.shape[1]), (0, 0)), constant_values=255) for s in strips])
        if sheet.shape[1] > 1800:
            sheet = cv2.resize(sheet, (1800, int(sheet.shape[0] * 1800 / sheet.shape[1])), interpolation=cv2.INTER_AREA)
        args.strip.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(args.strip), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
        print(f"\ncontact strip: {args.strip} ({sheet.shape[1]}x{sheet.shape[0]})", file=sys.stderr)


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "2")
    main()
