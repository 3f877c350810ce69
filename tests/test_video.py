"""Tests of facegeo.video: the frames of a video file, an animated GIF or a folder of frames."""

from __future__ import annotations

import math
import re

import cv2
import numpy as np
import pytest
from PIL import Image

from facegeo.errors import InputError
from facegeo.video import Frame, VideoInfo, open_video

W, H = 64, 48


def level(i: int) -> int:
    """The grey level frame ``i`` carries (far apart: survives mp4v/JPEG compression)."""
    return 10 + 20 * i


def coloured(i: int) -> np.ndarray:
    """(H, W, 3) uint8 RGB: frame ``i``'s grey level with a pure red left quarter (RGB order)."""
    img = np.full((H, W, 3), level(i), np.uint8)
    img[:, : W // 4] = (255, 0, 0)
    return img


def read_index(frame: Frame) -> int:
    """The index a frame carries, from the grey level of its right half."""
    return int(round((float(frame.image[:, W // 2:].mean()) - 10) / 20))


@pytest.fixture(scope="module")
def mp4(tmp_path_factory):
    """A 12-frame 64x48 mp4 (fourcc mp4v) at 10 fps; frame i is grey level(i), red on the left."""
    path = tmp_path_factory.mktemp("video") / "clip.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (W, H))
    assert writer.isOpened(), "this OpenCV build cannot write mp4v"
    for i in range(12):
        writer.write(cv2.cvtColor(coloured(i), cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def test_video_file_frames(mp4):
    info, frames = open_video(mp4)
    assert info == VideoInfo(str(mp4), 10.0, 12, W, H)
    frames = list(frames)
    assert [f.index for f in frames] == list(range(12))
    assert [read_index(f) for f in frames] == list(range(12))
    assert [f.time_s for f in frames] == [i / 10 for i in range(12)]
    first = frames[0].image
    assert first.shape == (H, W, 3) and first.dtype == np.uint8 and first.flags.c_contiguous
    r, g, b = first[:, :8].reshape(-1, 3).mean(axis=0)
    assert r > 200 and g < 50 and b < 50  # RGB, not OpenCV's BGR


@pytest.mark.parametrize("start, end, every, expected", [
    (0.3, 0.9, 2, [3, 5, 7]),
    (0.3, None, 1, list(range(3, 12))),
    (None, 0.35, 1, [0, 1, 2, 3]),
    (0.0, 1.2, 5, [0, 5, 10]),
    (1.1, 5.0, 1, [11]),
])
def test_video_file_range(mp4, start, end, every, expected):
    info, frames = open_video(mp4, start_s=start, end_s=end, every=every)
    frames = list(frames)
    assert [f.index for f in frames] == expected
    assert [read_index(f) for f in frames] == expected  # a seek lands on the right frame
    assert [f.time_s for f in frames] == [i / 10 for i in expected]


def test_fps_override(mp4, tmp_path):
    info, frames = open_video(mp4, start_s=1.0, fps=5.0)
    assert info.fps == 5.0 and [f.index for f in frames] == list(range(5, 12))


def test_lazy_iterator(mp4):
    info, frames = open_video(mp4)
    assert next(frames).index == 0 and next(frames).index == 1
    frames.close()  # releases the capture


def test_animated_gif(tmp_path):
    path = tmp_path / "clip.gif"
    images = [Image.fromarray(coloured(i)) for i in range(6)]
    images[0].save(path, save_all=True, append_images=images[1:], duration=50, loop=0)
    info, frames = open_video(path)
    assert info == VideoInfo(str(path), 20.0, 6, W, H)
    frames = list(frames)
    assert [f.index for f in frames] == list(range(6))
    assert [read_index(f) for f in frames] == list(range(6))
    assert [f.time_s for f in frames] == [i / 20 for i in range(6)]
    assert tuple(frames[2].image[0, 0]) == (255, 0, 0)
    _, frames = open_video(path, start_s=0.1, every=2)
    assert [(f.index, read_index(f)) for f in frames] == [(2, 2), (4, 4)]


def test_gif_without_durations_is_30_fps(tmp_path):
    path = tmp_path / "still.gif"
    Image.fromarray(coloured(1)).save(path)
    info, frames = open_video(path)
    assert info.fps == 30.0 and info.frame_count == 1 and len(list(frames)) == 1


def test_folder_of_frames(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for n in range(1, 11):  # frame_1.png ... frame_10.png: 2 before 10
        Image.fromarray(coloured(n - 1)).save(folder / f"frame_{n}.png")
    (folder / "notes.txt").write_text("not a frame")
    (folder / "cover.png").write_bytes(b"no number: not a frame")
    info, frames = open_video(folder)
    assert info == VideoInfo(str(folder), 30.0, 10, W, H, ("a folder of frames records no frame rate: 30 frames per second "
                                                           "assumed (--fps gives the rate)",))
    assert open_video(folder, fps=24)[0] == VideoInfo(str(folder), 24.0, 10, W, H)  # given: nothing assumed
    frames = list(frames)
    assert [f.index for f in frames] == list(range(10))
    assert [read_index(f) for f in frames] == list(range(10))
    assert frames[9].time_s == pytest.approx(9 / 30)
    assert tuple(frames[0].image[0, 0]) == (255, 0, 0)
    _, frames = open_video(folder, start_s=0.1, end_s=0.3, every=3, fps=10)
    assert [(f.index, read_index(f)) for f in frames] == [(1, 1)]
    _, frames = open_video(folder, start_s=0.1, every=3, fps=10)
    assert [f.index for f in frames] == [1, 4, 7]


def test_a_gap_in_a_folders_numbering_is_told(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for n in [*range(0, 10), *range(15, 20), 22]:  # 10-14, 20 and 21 missing
        Image.fromarray(coloured(n % 10)).save(folder / f"frame_{n:04d}.png")
    info, frames = open_video(folder, fps=30)
    assert info.notes == ("frame numbers 10-14, 20-21 missing: the frames are timed one after another, as if none were missing",)
    assert [f.index for f in frames] == list(range(16))


def test_folder_frame_of_another_size(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    Image.fromarray(coloured(0)).save(folder / "0001.png")
    Image.fromarray(np.zeros((H + 2, W, 3), np.uint8)).save(folder / "0002.png")
    info, frames = open_video(folder)
    assert next(frames).index == 0
    with pytest.raises(InputError, match=r"^.*0002\.png: image size: expected 64x48 px.*found 64x50 px"):
        next(frames)


def test_missing_and_unreadable_sources(tmp_path):
    missing = tmp_path / "nope.mp4"
    with pytest.raises(InputError, match=rf"^{re.escape(str(missing))}: file: expected a video .* found no such file"):
        open_video(missing)
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"this is not a video at all" * 50)
    with pytest.raises(InputError, match=rf"^{re.escape(str(junk))}: video: expected a video \(mp4, mov, avi, webm, mkv\), an animated GIF or a folder"):
        open_video(junk)
    empty = tmp_path / "empty.mov"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match=rf"^{re.escape(str(empty))}: video: expected a video"):
        open_video(empty)
    photo = tmp_path / "photo.png"
    Image.fromarray(coloured(0)).save(photo)
    with pytest.raises(InputError, match=rf"^{re.escape(str(photo))}: file: expected a video .* found a single PNG image"):
        open_video(photo)
    bad_gif = tmp_path / "bad.gif"
    bad_gif.write_bytes(b"GIF89a" + b"\x00" * 5)
    with pytest.raises(InputError, match=rf"^{re.escape(str(bad_gif))}: video: expected a video"):
        open_video(bad_gif)
    folder = tmp_path / "empty_folder"
    folder.mkdir()
    (folder / "readme.txt").write_text("1 2 3")
    with pytest.raises(InputError, match=rf"^{re.escape(str(folder))}: frames: expected .* found no numbered image files"):
        open_video(folder)


@pytest.mark.parametrize("kwargs, field", [
    ({"start_s": -0.1}, "--start"),
    ({"start_s": math.nan}, "--start"),
    ({"start_s": math.inf}, "--start"),
    ({"end_s": 0.0}, "--end"),
    ({"start_s": 0.5, "end_s": 0.5}, "--end"),
    ({"start_s": 0.5, "end_s": 0.2}, "--end"),
    ({"end_s": math.nan}, "--end"),
    ({"end_s": math.inf}, "--end"),  # no end is None; inf overflowed the frame arithmetic (a traceback from track)
    ({"start_s": 1e308}, "--start"),  # start × fps overflows: after the clip's end, not an OpenCV failure
    ({"every": 0}, "--every"),
    ({"every": 1.5}, "--every"),
    ({"every": True}, "--every"),
    ({"fps": 0}, "--fps"),
    ({"fps": math.nan}, "--fps"),
])
def test_invalid_range(mp4, kwargs, field):
    with pytest.raises(InputError, match=rf"^{re.escape(str(mp4))}: {field}: expected"):
        open_video(mp4, **kwargs)


def test_an_end_beyond_any_frame_keeps_every_frame(mp4):
    _, frames = open_video(mp4, end_s=1e308)  # end × fps overflows to inf: no end
    assert len(list(frames)) == 12


def test_no_frames_in_range(mp4, tmp_path):
    with pytest.raises(InputError, match=rf"^{re.escape(str(mp4))}: --start: expected a time before the source's end \(12 frames, 1.2 s"):
        open_video(mp4, start_s=1.2)
    with pytest.raises(InputError, match=rf"^{re.escape(str(mp4))}: --start/--end: expected a range holding at least one frame"):
        open_video(mp4, start_s=0.31, end_s=0.39)
    path = tmp_path / "clip.gif"
    images = [Image.fromarray(coloured(i)) for i in range(3)]
    images[0].save(path, save_all=True, append_images=images[1:], duration=50, loop=0)
    with pytest.raises(InputError, match=rf"^{re.escape(str(path))}: --start: "):
        open_video(path, start_s=0.15)
