"""dlib's ensemble-of-regression-trees shape predictor (Kazemi & Sullivan 2014), evaluated with NumPy.

Why hand-written: ``dlib.shape_predictor(path)`` spends ~0.9 s per process deserialising the
99.7 MB ``.dat`` file of the 68-point model, holding the GIL throughout (so it cannot even be
overlapped with other work), while the prediction itself takes ~3 ms. This module converts the
``.dat`` once into a cache of ``.npy`` files (:func:`cached_predictor`) that later processes
memory-map in milliseconds, and evaluates the cascade with the same arithmetic as dlib, so the
68 points are the same integer pixels.

The model (dlib's serialisation, version 1): a mean shape of P points in box-normalised
coordinates (the box's top-left corner at (0, 0), its bottom-right at (1, 1)); C cascade levels,
each with F feature pixels (an anchor point of the mean shape + an offset from it, in normalised
units) and T regression trees of depth D (2^D − 1 splits comparing the intensities of two feature
pixels with a threshold, 2^D leaves each holding a (P·2,) shape increment). Per level: the
similarity transform taking the mean shape to the current one moves the offsets; each feature
pixel is placed at its anchor in the current shape + the moved offset, mapped into the box, rounded
to the nearest pixel (half up) and read as the integer mean of its R, G, B (0 outside the image);
every tree adds its leaf's increment to the current shape, in order, in float32. The final shape is
mapped into the box and rounded to whole pixels.

The file is a stream of dlib's variable-length integers (a control byte: bits 0-3 the byte count,
bit 7 the sign; then the magnitude, little-endian); a float is two of them (mantissa, exponent:
value = mantissa · 2^exponent); a vector is its length followed by its elements; a matrix its
negated row and column counts followed by its elements. :func:`convert_predictor` splits the
stream into integers with a vectorised speculative scan (:func:`_token_starts`), then reads the
(uniform) structure with array indexing.
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeo.cache_dir import cache_dir as default_cache_dir
from facegeo.errors import ModelFileError

__all__ = ["ShapePredictor", "convert_predictor", "cached_predictor", "CACHE_FORMAT"]

#: Bumped when the cached arrays' layout changes, so an old cache is never read as a new one.
CACHE_FORMAT = 1
_ARRAYS = ("mean", "split_idx", "split_thresh", "leaves", "anchor", "delta")
_SPECIAL_EXPONENT = 32000  # dlib's exponents ≥ this stand for ±inf and NaN
_CHUNK = 4096  # bytes per lane of the speculative integer scan


@dataclass(frozen=True)
class _Plan:
    """A :class:`ShapePredictor`'s arrays as :meth:`ShapePredictor.__call__` reads them: the mean
    shape centred (P, 2) float64 and its spread; the feature offsets' x and y (C, F) float32; each
    level's splits' two feature pixels (C, T·S) and thresholds (C, T·S); the first split (T,) and
    the leaf row offset (T,) of each tree; the leaves (C, T·(S + 1), P·2)."""

    mean_centred: np.ndarray
    spread: float
    delta_x: np.ndarray
    delta_y: np.ndarray
    first: np.ndarray
    second: np.ndarray
    thresh: np.ndarray
    tree_splits: np.ndarray
    tree_leaves: np.ndarray
    leaves: np.ndarray


@dataclass(frozen=True)
class ShapePredictor:
    """A converted dlib shape predictor (arrays possibly views of read-only memory maps).

    mean: (P, 2) float32 mean shape, box-normalised (x, y).
    split_idx: (C, T, S, 2) int16 feature-pixel indices compared by each split (S = 2^D − 1).
    split_thresh: (C, T, S) float32 thresholds on the intensity difference.
    leaves: (C, T, S + 1, P·2) float32 shape increments (x0, y0, x1, y1, …), box-normalised.
    anchor: (C, F) int16 index of the mean-shape point each feature pixel hangs from.
    delta: (C, F, 2) float32 offset of each feature pixel from its anchor, box-normalised.
    """

    mean: np.ndarray
    split_idx: np.ndarray
    split_thresh: np.ndarray
    leaves: np.ndarray
    anchor: np.ndarray
    delta: np.ndarray

    @functools.cached_property
    def _plan(self) -> _Plan:
        """The arrays :meth:`__call__` reads, laid out for it once per predictor object (the
        frozen dataclass's ``__dict__`` keeps it: ``cached_property`` does not go through
        ``__setattr__``)."""
        levels, trees, splits = self.split_idx.shape[:3]
        mean = self.mean.astype(np.float64)
        mean_centred = mean - mean.mean(axis=0)
        pairs = self.split_idx.reshape(levels, trees * splits, 2)
        return _Plan(mean_centred, float((mean_centred**2).sum()),
                     np.ascontiguousarray(self.delta[..., 0]), np.ascontiguousarray(self.delta[..., 1]),
                     np.ascontiguousarray(pairs[..., 0]).astype(np.intp), np.ascontiguousarray(pairs[..., 1]).astype(np.intp),
                     self.split_thresh.reshape(levels, trees * splits), np.arange(trees) * splits,
                     np.arange(trees) * (splits + 1) - splits, self.leaves.reshape(levels, trees * (splits + 1), -1))

    def __call__(self, image: np.ndarray, box: tuple[int, int, int, int], mirror: bool = False) -> np.ndarray:
        """The P points of the face in ``box`` as dlib's ``shape_predictor(image, rectangle)``
        gives them.

        image: (H, W, 3) uint8 RGB or (H, W) uint8 grey. box: (left, top, right, bottom) whole
        pixels, right/bottom inclusive (a ``dlib.rectangle``). Returns (P, 2) float64 whole-pixel
        (x, y) coordinates, pixel centres at integers (dlib's convention). ``mirror``: the image is
        read as its mirror image left-right (``box`` and the points in its pixels), with no copy.
        """
        if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
            raise ValueError(f"shape predictor: expected an (H, W, 3) or (H, W) uint8 image, got {image.dtype} {image.shape}")
        left, top, right, bottom = (int(v) for v in box)
        origin = np.array([left, top], dtype=np.float64)
        size = np.array([right - left, bottom - top], dtype=np.float64)
        limit = np.array([image.shape[1] - 1, image.shape[0] - 1])
        plan = self._plan
        levels, trees = self.split_idx.shape[:2]
        depth = int(np.log2(self.split_idx.shape[2] + 1))
        shape = self.mean.reshape(-1).copy()
        summed = np.empty((trees + 1, shape.size), np.float32)  # the shape, then each tree's increment
        for level in range(levels):
            points = shape.reshape(-1, 2)
            # Similarity transform (least squares, Umeyama) from the mean shape to the current
            # one: in 2-D its scaled rotation is [[p, -q], [q, p]] / spread of the mean shape.
            current = points.astype(np.float64)
            cov = (current - current.mean(axis=0)).T @ plan.mean_centred
            p, q = (cov[0, 0] + cov[1, 1]) / plan.spread, (cov[1, 0] - cov[0, 1]) / plan.spread
            r00, r01, r10, r11 = np.float32(p), np.float32(-q), np.float32(q), np.float32(p)
            dx, dy = plan.delta_x[level], plan.delta_y[level]
            anchored = points[self.anchor[level]]
            fx = (r00 * dx + r01 * dy) + anchored[:, 0]  # float32, dlib's order
            fy = (r10 * dx + r11 * dy) + anchored[:, 1]
            x = np.floor(origin[0] + size[0] * fx.astype(np.float64) + 0.5).astype(np.int64)
            y = np.floor(origin[1] + size[1] * fy.astype(np.float64) + 0.5).astype(np.int64)
            inside = (x >= 0) & (x <= limit[0]) & (y >= 0) & (y <= limit[1])
            x, y = (limit[0] - x[inside] if mirror else x[inside]), y[inside]
            values = np.zeros(len(inside), dtype=np.float32)
            if image.ndim == 3:
                values[inside] = image[y, x].astype(np.uint16).sum(axis=1) // 3
            else:
                values[inside] = image[y, x]
            # every split of the level judged at once, then each tree walked down its decisions
            right_branch = values[plan.first[level]] - values[plan.second[level]] <= plan.thresh[level]
            node = np.zeros(trees, dtype=np.int64)
            for _ in range(depth):
                node = 2 * node + 1 + right_branch[plan.tree_splits + node]
            summed[0] = shape
            np.take(plan.leaves[level], plan.tree_leaves + node, axis=0, out=summed[1:])
            # dlib adds the trees' increments one after the other in float32; a reduction over
            # the first axis does the same (NumPy sums pairwise only along the contiguous axis).
            shape = np.add.reduce(summed, axis=0)
        final = origin + size * shape.reshape(-1, 2).astype(np.float64)
        return np.floor(final + 0.5)


# ------------------------------------------------------------------------------------ conversion
def _token_starts(data: np.ndarray, source: Path) -> np.ndarray:
    """Byte offsets (N,) int64 of the variable-length integers that make up ``data`` ((n,) uint8,
    the whole file), in order.

    Where one integer ends depends on the previous one, so a plain scan is sequential. Instead the
    file is cut into lanes of :data:`_CHUNK` bytes, each scanned from its first byte in lockstep
    with all others (vectorised); a lane's guess joins the true sequence as soon as both hit the
    same offset (a few integers in). Walking the lanes in order, the true sequence enters each
    lane at the offset where the previous one left it and is followed one integer at a time until
    it reaches an offset the lane's scan visited; from there on the lane's offsets are the true
    ones.
    """
    n = len(data)
    step = np.zeros(n + 16, dtype=np.uint8)  # an integer starting here is this long; 0 past the end
    np.add(data & 0x0F, 1, out=step[:n])
    lane_start = np.arange(0, n, _CHUNK, dtype=np.int64)
    lane_end = np.minimum(lane_start + _CHUNK, n)
    lane_exit = np.full(len(lane_start), n, dtype=np.int64)  # where each lane's scan leaves it
    visited = np.zeros(n + 16, dtype=bool)
    pos = lane_start.copy()
    running = np.ones(len(pos), dtype=bool)
    while running.any():  # finished lanes are parked at n (step 0)
        visited[pos] = True
        pos += step[pos]
        left = running & (pos >= lane_end)
        if left.any():
            lane_exit[left] = pos[left]
            pos[left] = n
            running &= ~left
    walked: list[int] = []
    entry = 0
    for lane, (first, end) in enumerate(zip(lane_start.tolist(), lane_end.tolist())):
        if entry >= n:
            raise ModelFileError(source, "dlib model stream", "complete variable-length integers", "a truncated file")
        joined = entry
        while joined < end and not visited[joined]:  # follow the true sequence until the lane's scan joins it
            walked.append(joined)
            joined += int(step[joined])
        visited[first:joined] = False  # the lane's guesses before it joined
        entry = int(lane_exit[lane]) if joined < end else joined
    if entry != n:
        raise ModelFileError(source, "dlib model stream", "complete variable-length integers", "a truncated file")
    visited[np.array(walked, dtype=np.int64)] = True
    return np.flatnonzero(visited[:n])


def _token_values(data: np.ndarray, starts: np.ndarray, source: Path) -> np.ndarray:
    """The signed integers (N,) int64 at byte offsets ``starts`` of ``data``."""
    control = data[starts]
    size = control & 0x0F
    if np.any(control & 0x70) or np.any(size == 0) or np.any(size > 8):
        raise ModelFileError(source, "dlib model stream", "variable-length integers (control bytes 0x01-0x08, 0x81-0x88)",
                             "other bytes")
    widest = int(size.max())
    kind = np.int32 if widest <= 3 else np.int64  # int32 holds 3-byte magnitudes (all a float32 needs)
    padded = np.concatenate([data, np.zeros(9, dtype=np.uint8)])
    at = starts + 1
    value = padded[at].astype(kind)
    for k in range(1, widest):
        at += 1
        byte = padded[at] & np.where(size > k, np.uint8(0xFF), np.uint8(0))
        value |= byte.astype(kind) << kind(8 * k)  # 8-byte magnitudes wrap, as dlib's int64 does
    np.negative(value, out=value, where=(control & 0x80) != 0)
    return value.astype(np.int64, copy=False)


def _floats(mantissa: np.ndarray, exponent: np.ndarray, source: Path, field: str) -> np.ndarray:
    """dlib's (mantissa, exponent) pairs -> float32 values, as dlib reads them into a float."""
    if np.any(exponent >= _SPECIAL_EXPONENT) or np.any(np.abs(mantissa) >= 2**24):
        raise ModelFileError(source, field, "finite float32 values", "infinite, NaN or wider values")
    return np.ldexp(mantissa.astype(np.float32), exponent.astype(np.int32)).astype(np.float32)


class _Reader:
    """Sequential reads of the integer stream (scalars only; blocks are read by the caller)."""

    def __init__(self, values: np.ndarray, source: Path):
        self.values, self.source, self.at = values, source, 0

    def take(self, field: str, expected: str, allowed: range | None = None) -> int:
        if self.at >= len(self.values):
            raise ModelFileError(self.source, field, expected, "the end of the file")
        value = int(self.values[self.at])
        if allowed is not None and value not in allowed:
            raise ModelFileError(self.source, field, expected, str(value))
        self.at += 1
        return value

    def block(self, count: int, field: str) -> np.ndarray:
        if self.at + count > len(self.values):
            raise ModelFileError(self.source, field, f"{count} more integers", "the end of the file")
        out = self.values[self.at:self.at + count]
        self.at += count
        return out


def convert_predictor(path: str | Path) -> ShapePredictor:
    """Read a dlib shape predictor ``.dat`` file (version 1; all trees of one depth, every level
    with the same numbers of trees and feature pixels, as dlib's trainer writes them) into arrays.

    Takes ~2 s for the 99.7 MB 68-point model. Raises :class:`ModelFileError` naming the file and
    the field when the file is missing, truncated or not such a model.
    """
    source = Path(path)
    try:
        data = np.fromfile(source, dtype=np.uint8)
    except OSError as exc:
        raise ModelFileError(source, "dlib shape predictor", "a readable .dat file", str(exc)) from None
    if len(data) == 0:
        raise ModelFileError(source, "dlib shape predictor", "a dlib .dat model", "an empty file")
    values = _token_values(data, _token_starts(data, source), source)
    read = _Reader(values, source)
    read.take("version", "1", range(1, 2))
    rows, cols = abs(read.take("mean shape rows", "an even count")), abs(read.take("mean shape columns", "1", range(-1, 2)))
    if rows == 0 or rows % 2 or cols != 1:
        raise ModelFileError(source, "mean shape", "an (even, 1) matrix", f"({rows}, {cols})")
    parts = rows // 2
    mean = read.block(2 * rows, "mean shape").reshape(-1, 2)
    mean = _floats(mean[:, 0], mean[:, 1], source, "mean shape").reshape(parts, 2)
    levels = read.take("cascade levels", "a positive count", range(1, 10_000))
    trees = read.take("trees per level", "a positive count", range(1, 1_000_000))
    splits = read.take("splits per tree", "2^depth - 1", range(1, 1 << 20))
    leaves = splits + 1
    if leaves & splits:
        raise ModelFileError(source, "splits per tree", "2^depth - 1", str(splits))
    # Per tree: [splits count] splits×(idx1, idx2, mantissa, exponent) [leaves count]
    # leaves×(rows, columns, rows×(mantissa, exponent)); per level: [trees count] trees×tree.
    tree_len = 1 + 4 * splits + 1 + leaves * (2 + 2 * rows)
    level_len = 1 + trees * tree_len
    read.at -= 2  # back to the first level's tree count
    body = read.block(levels * level_len, "regression trees").reshape(levels, level_len)
    if np.any(body[:, 0] != trees):
        raise ModelFileError(source, "trees per level", f"{trees} on every level", "levels of other sizes")
    trees_arr = body[:, 1:].reshape(levels, trees, tree_len)
    if np.any(trees_arr[:, :, 0] != splits) or np.any(trees_arr[:, :, 1 + 4 * splits] != leaves):
        raise ModelFileError(source, "regression trees", f"every tree with {splits} splits and {leaves} leaves", "trees of other sizes")
    split = trees_arr[:, :, 1:1 + 4 * splits].reshape(levels, trees, splits, 4)
    leaf = trees_arr[:, :, 2 + 4 * splits:].reshape(levels, trees, leaves, 2 + 2 * rows)
    if np.any(np.abs(leaf[..., 0]) != rows) or np.any(np.abs(leaf[..., 1]) != 1):
        raise ModelFileError(source, "leaf values", f"({rows}, 1) matrices", "other shapes")
    leaf_values = _floats(leaf[..., 2::2], leaf[..., 3::2], source, "leaf values")
    thresh = _floats(split[..., 2], split[..., 3], source, "split thresholds")
    read.take("anchor levels", f"{levels}", range(levels, levels + 1))
    features = read.take("feature pixels per level", "a positive count", range(1, 1 << 15))
    read.at -= 1
    anchor = read.block(levels * (1 + features), "anchor points").reshape(levels, 1 + features)
    read.take("offset levels", f"{levels}", range(levels, levels + 1))
    offsets = read.block(levels * (1 + 4 * features), "pixel offsets").reshape(levels, 1 + 4 * features)
    if np.any(anchor[:, 0] != features) or np.any(offsets[:, 0] != features):
        raise ModelFileError(source, "feature pixels per level", f"{features} on every level", "levels of other sizes")
    if read.at != len(values):
        raise ModelFileError(source, "dlib shape predictor", "the end of the file after the pixel offsets",
                             f"{len(values) - read.at} more integers")
    anchor = anchor[:, 1:]
    if np.any(anchor < 0) or np.any(anchor >= parts) or np.any(split[..., :2] < 0) or np.any(split[..., :2] >= features):
        raise ModelFileError(source, "feature indices", f"anchors < {parts} and split pixels < {features}", "indices out of range")
    offsets = offsets[:, 1:].reshape(levels, features, 2, 2)
    delta = _floats(offsets[..., 0], offsets[..., 1], source, "pixel offsets")
    return ShapePredictor(mean, split[..., :2].astype(np.int16), thresh, leaf_values, anchor.astype(np.int16), delta)


# ------------------------------------------------------------------------------------------ cache
def _stamp(path: Path) -> str:
    """A name for one install of the file ``path``: its path, size and modification time, hashed."""
    stat = path.stat()
    return hashlib.sha256(f"{path.resolve()}|{stat.st_size}|{stat.st_mtime_ns}".encode()).hexdigest()[:32]


def _content_digest(path: Path, root: Path) -> tuple[str, bool]:
    """The SHA-256 (32 hex digits) of the ``.dat`` file ``path``'s content, the cache folder's key,
    so that the same file installed again (a new venv, a new modification time) finds its folder
    instead of adding another 64 MB one; and whether it was remembered for this install under
    ``root`` / ``dlib-predictor-sources`` (:func:`_remember_digest`) rather than computed (~0.07 s
    for the 100 MB model)."""
    try:
        digest = (root / "dlib-predictor-sources" / _stamp(path)).read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        digest = ""
    if re.fullmatch(r"[0-9a-f]{32}", digest):
        return digest, True
    with path.open("rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()[:32], False


def _remember_digest(path: Path, root: Path, digest: str) -> None:
    """Keeps ``digest`` for this install of ``path`` (a 32-byte file, staged and renamed into
    place like the folders); an unwritable cache computes it again next time."""
    memo = root / "dlib-predictor-sources" / _stamp(path)
    staged = None
    try:
        memo.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", encoding="ascii", dir=memo.parent, prefix=f".{memo.name}.", delete=False) as handle:
            staged = Path(handle.name)
            handle.write(digest)
        os.replace(staged, memo)
    except OSError:
        if staged is not None:
            staged.unlink(missing_ok=True)


def _stale_folders(root: Path, stem: str) -> list[Path]:
    """Cache folders of ``stem`` that no current key can name: the earlier layout's (named by the
    file's size and modification time, one per install) and other formats'."""
    current = re.compile(rf"dlib-predictor-v{CACHE_FORMAT}-{re.escape(stem)}-[0-9a-f]{{32}}")
    ours = re.compile(rf"dlib-predictor-v\d+-{re.escape(stem)}-(\d+-\d+|[0-9a-f]{{32}})")
    return [f for f in root.iterdir() if ours.fullmatch(f.name) and not current.fullmatch(f.name) and f.is_dir()]


def _load_cached(folder: Path) -> ShapePredictor | None:
    try:
        # Plain ndarray views of the memory maps (np.memmap's subclass costs time on every operation).
        return ShapePredictor(**{name: np.asarray(np.load(folder / f"{name}.npy", mmap_mode="r")) for name in _ARRAYS})
    except (OSError, ValueError):
        return None


def cached_predictor(path: str | Path, cache_dir: str | Path | None = None) -> ShapePredictor:
    """The predictor of the ``.dat`` file ``path``, memory-mapped from the cache (milliseconds);
    converted and stored there first when missing (:func:`convert_predictor`, ~2 s).

    The cache entry is a folder of ``.npy`` files under ``cache_dir`` (default
    :func:`facegeo.cache_dir.cache_dir`) keyed by the file's name and a digest of its content
    (:func:`_content_digest`), so reinstalling the same file reuses it; it is written to a temporary
    folder and renamed into place, so a reader never sees half of one, and then the file name's
    folders that no current key names (the earlier layout's, one per install) are removed. An
    unwritable cache only costs the conversion on every call.
    """
    source = Path(path)
    if not source.is_file():
        raise ModelFileError(source, "dlib shape predictor", "an existing .dat file", "no such file")
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    digest, remembered = _content_digest(source, root)
    folder = root / f"dlib-predictor-v{CACHE_FORMAT}-{source.stem}-{digest}"
    if folder.is_dir() and (found := _load_cached(folder)) is not None:
        if not remembered:
            _remember_digest(source, root, digest)
        return found
    predictor = convert_predictor(source)
    try:
        root.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=root))
    except OSError:
        return predictor
    try:
        for name in _ARRAYS:
            np.save(staging / f"{name}.npy", np.ascontiguousarray(getattr(predictor, name)))
        os.replace(staging, folder)
        _remember_digest(source, root, digest)
        for stale in _stale_folders(root, source.stem):  # (a process still mapping one keeps its files until it exits)
            shutil.rmtree(stale, ignore_errors=True)
    except OSError:  # another process stored it first (or the disk is full): keep what we have
        pass
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    return _load_cached(folder) or predictor
