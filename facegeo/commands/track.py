"""``facegeo track VIDEO -o OUT``: the face through a video as a Live Link Face take and the
person's asset animated by it, through :func:`facegeo.jobs.track_into_folder` (``take.csv``,
``track.json``, ``asset/``, ``face.glb``, ``face.usdz``, ``preview.png``)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from facegeo.commands.arguments import COMMAND_LINE, Command, add_model_argument
from facegeo.errors import InputError

__all__ = ["COMMANDS"]


def _arguments(parser: argparse.ArgumentParser) -> None:
    from facegeo.commands.arguments import DETECTOR_NAMES

    parser.add_argument("video", type=Path, metavar="VIDEO",
                        help="a video (mp4, mov, avi, webm, mkv), an animated GIF or a folder of numbered frames")
    parser.add_argument("-o", "--output", type=Path, required=True,
                        help="output folder (created; an existing one must be empty or an earlier facegeo output)")
    parser.add_argument("--start", type=float, default=None, metavar="S", help="first second to track (default: the start)")
    parser.add_argument("--end", type=float, default=None, metavar="S", help="track up to this second (default: the end)")
    parser.add_argument("--every", type=int, default=1, metavar="N", help="track every N-th frame (default 1: all)")
    parser.add_argument("--fps", type=float, default=None, metavar="FPS",
                        help="the frames' rate, for a folder of frames or a video that records none or a wrong one "
                             "(default: the video's, else 30)")
    group = parser.add_argument_group("fitting")
    add_model_argument(group)
    group.add_argument("--landmarks", choices=DETECTOR_NAMES, default="lids", metavar="NAME",
                       help="landmark detector, one of %(choices)s (default: lids = hybrid with the Face Landmarker's "
                            "mesh and its eyelids, which close on a blink)")
    group.add_argument("--focal", type=float, default=None, metavar="PX",
                       help="focal length in pixels of the frames; default: one focal for the clip, estimated from the face")
    group.add_argument("--keyframes", type=int, default=5, metavar="K",
                       help="frames spanning the head's turn that the identity is fitted to (default 5)")
    parser.add_argument("--neutral", default="auto", metavar="S|auto|none",
                        help="seconds into the video at which the face is at rest: the person's landmarks at rest are measured there "
                             "and every expression from them, as Live Link Face's calibration; auto (the default): at the clip's "
                             "most typical still stretch where it holds the face at rest (a note says where, or that none does); "
                             "none: the points as observed")
    parser.add_argument("--no-smooth", action="store_true",
                        help="write each frame's own fit (no smoothing of the pose and the weights over neighbouring frames)")
    parser.add_argument("--no-asset", action="store_true",
                        help="write the take and track.json only (no textured asset, animated face.glb/face.usdz, preview)")


def _run(args: argparse.Namespace) -> None:
    from facegeo.jobs import TrackOptions, track_into_folder

    if args.keyframes < 1:  # (--start, --end, --every and --fps are checked by facegeo.video.open_video, naming the video)
        raise InputError(COMMAND_LINE, "--keyframes", "an integer >= 1", str(args.keyframes))
    neutral_s = None
    if args.neutral not in ("auto", "none"):
        try:
            neutral_s = float(args.neutral)
        except ValueError:
            neutral_s = math.nan
        if not (math.isfinite(neutral_s) and neutral_s >= 0):
            raise InputError(COMMAND_LINE, "--neutral", "a time in seconds >= 0, auto or none", args.neutral)
    options = TrackOptions(model=args.model, landmarks=args.landmarks, focal=args.focal, start_s=args.start, end_s=args.end,
                           every=args.every, keyframes=args.keyframes, asset=not args.no_asset,
                           smooth=not args.no_smooth, neutral_s=neutral_s, fps=args.fps, find_rest=args.neutral == "auto")
    live = sys.stderr.isatty()

    def progress(frames: int, rate: float) -> None:
        if live:
            print(f"\rtracking: {frames} frames, {rate:.1f} frames/s", end="", file=sys.stderr, flush=True)

    record = track_into_folder(args.video, args.output, options, progress)
    if live:
        print(file=sys.stderr)
    for note in record["notes"]:
        print(f"note: {note}")
    lost = record["frames_tracked"] - record["frames_with_face"]
    count = record["frames_tracked"]
    print(f"tracked {args.video}: {count} frame{'' if count == 1 else 's'} ({lost} without a face), keyframes {record['keyframes']}, "
          f"{record['frames_per_second']:.1f} frames/s")
    extra = "" if args.no_asset else ", asset/, face.glb, face.usdz, preview.png"
    print(f"wrote {args.output}/take.csv, track.json{extra}")


COMMANDS = (
    Command(
        "track",
        help="track a face through a video: a Live Link Face take, per-frame fits and the person's animated asset",
        description="Fit one identity to keyframes spanning the head's turn, then the pose and expression of every "
        "frame; write take.csv (Live Link Face's layout: 52 ARKit weights and the head's rotation per frame, readable "
        "by facegeo animate and Unreal), track.json (per frame: face found, landmark RMS, pose, weights) and the "
        "person's textured asset from the most frontal keyframe with face.glb and face.usdz animated by the take.",
        arguments=_arguments,
        run=_run,
        output_folder=True,
    ),
)
