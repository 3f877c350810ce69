"""facegeo.observed_frames: a clip's observations in an unnamed temporary file."""

from __future__ import annotations

import errno
import os
import tempfile

import numpy as np
import pytest

from facegeo.camera import Camera
from facegeo.errors import OutputError
from facegeo.fitting.landmark_problem import SurfacePoints
from facegeo.fitting.photo_fit import PhotoObservation
from facegeo.observed_frames import NOTE_BYTES, ObservedFrame, ObservedFrames

K = 7  # dense points of the toy correspondence


@pytest.fixture()
def correspondence() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    barycentric = rng.random((K, 3))
    return rng.integers(0, 100, (K, 3)), barycentric / barycentric.sum(1, keepdims=True)


def _frame(index: int, correspondence: tuple[np.ndarray, np.ndarray] | None, face: bool = True, dense: bool = True,
           note: str | None = None) -> ObservedFrame:
    rng = np.random.default_rng(index)
    if not face:
        return ObservedFrame(index, index / 30, None, note)
    surface = None
    if dense:
        surface = SurfacePoints(rng.normal(size=(K, 2)) * 100, correspondence[0], correspondence[1], rng.random(K),
                                rng.random(K) < 0.3, rng.random(K) < 0.8)
    empty = np.zeros((0, 0, 3), np.uint8)
    observation = PhotoObservation(empty, "<clip>", empty, None, rng.normal(size=(88, 2)) * 50 + 200,
                                   Camera(700.0 + index, 320.0, 240.5, 640, 480, index % 2 == 0), None,
                                   rng.random(88).astype(np.float32), surface, {}, [])
    return ObservedFrame(index, index / 30, observation, note, rng.random(2) * 10, followed_back=index % 3 == 2)


def _assert_same(a: ObservedFrame, b: ObservedFrame) -> None:
    assert (a.index, a.time_s, a.note, a.followed_back) == (b.index, b.time_s, b.note, b.followed_back)
    assert (a.lid_gaps is None) == (b.lid_gaps is None)
    if a.lid_gaps is not None:
        np.testing.assert_array_equal(a.lid_gaps, b.lid_gaps)
    assert (a.observation is None) == (b.observation is None)
    if a.observation is None:
        return
    p, q = a.observation, b.observation
    assert p.camera == q.camera and p.source == q.source
    np.testing.assert_array_equal(p.landmarks, q.landmarks)
    assert p.weights.dtype == q.weights.dtype == np.float32
    np.testing.assert_array_equal(p.weights, q.weights)
    assert (p.surface_points is None) == (q.surface_points is None)
    if p.surface_points is not None:
        for name in ("targets", "vertex_ids", "barycentric", "weights", "contour", "expressive"):
            x, y = getattr(p.surface_points, name), getattr(q.surface_points, name)
            assert x.dtype == y.dtype, name
            np.testing.assert_array_equal(x, y, err_msg=name)


def test_frames_come_back_bit_for_bit_in_order(correspondence):
    frames = [_frame(0, correspondence), _frame(1, correspondence, face=False, note="no face: too dark"),
              _frame(2, correspondence, dense=False), _frame(3, correspondence)]
    store = ObservedFrames(None, "<clip>", correspondence)
    for frame in frames:
        store.append(frame)
    assert len(store) == 4
    for a, b in zip(frames, store):
        _assert_same(a, b)
    _assert_same(store[-1], frames[-1])
    assert [f.index for f in store[1:3]] == [1, 2]
    with pytest.raises(IndexError):
        store[4]
    store.close()


def test_a_long_note_is_cut_at_a_character_boundary(correspondence):
    store = ObservedFrames(None, "<clip>", correspondence)
    store.append(_frame(0, correspondence, face=False, note="é" * NOTE_BYTES))
    note = store[0].note
    assert note == "é" * (NOTE_BYTES // 2) and len(note.encode("utf-8")) <= NOTE_BYTES


def test_dense_points_elsewhere_on_the_model_are_refused(correspondence):
    store = ObservedFrames(None, "<clip>", correspondence)
    moved = (correspondence[0] + 1, correspondence[1])
    with pytest.raises(ValueError, match="elsewhere"):
        store.append(_frame(0, moved))
    with pytest.raises(ValueError, match="elsewhere"):
        ObservedFrames(None, "<clip>", None).append(_frame(0, correspondence))


def test_extend_copies_another_store_and_closes_it(correspondence):
    first, second = ObservedFrames(None, "<clip>", correspondence), ObservedFrames(None, "<clip>", correspondence)
    first.append(_frame(0, correspondence))
    for k in (1, 2):
        second.append(_frame(k, correspondence))
    assert first.extend(second) is first and len(first) == 3 and len(second) == 0
    for k, frame in enumerate(first):
        _assert_same(frame, _frame(k, correspondence))
    first.extend(iter([_frame(3, correspondence)]))  # any frames
    assert [f.index for f in first] == [0, 1, 2, 3]


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork")
def test_a_forked_child_fills_a_store_that_its_caller_reads(correspondence):
    from facegeo.forked_call import fork_call

    store = ObservedFrames(None, "<clip>", correspondence)
    mine = ObservedFrames(None, "<clip>", correspondence)
    mine.append(_frame(0, correspondence))

    def child(part: ObservedFrames) -> int:
        for k in (1, 2, 3):
            part.append(_frame(k, correspondence))
        return len(part)

    assert fork_call(child, store).result() == 3
    assert len(store) == 0 and len(store.sync()) == 3  # the caller takes the child's records
    mine.extend(store)
    for k, frame in enumerate(mine):
        _assert_same(frame, _frame(k, correspondence))
    # a record cut short (a child killed while writing) is left out, and the store can start again
    cut = ObservedFrames(None, "<clip>", correspondence)
    cut.append(_frame(0, correspondence))
    os.pwrite(cut._file.fileno(), b"\1" * 10, cut._record)
    assert len(cut.sync()) == 1
    assert len(cut.clear()) == 0 and os.fstat(cut._file.fileno()).st_size == 0


def test_the_file_has_no_name_and_a_full_disk_is_a_clear_error(correspondence, monkeypatch, tmp_path):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    store = ObservedFrames(None, "<clip>", correspondence)
    store.append(_frame(0, correspondence))
    assert list(tmp_path.iterdir()) == []  # nothing to leave behind, however the process ends

    def full(*args):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "pwrite", full)
    with pytest.raises(OutputError, match="no space left on the device.*TMPDIR") as caught:
        store.append(_frame(1, correspondence))
    assert caught.value.path == str(tmp_path)
    assert len(store) == 1
