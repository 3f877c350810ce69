"""Shared helpers of the ARKit / Live Link Face tests (no tests here): synthetic takes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facegeo.export.live_link import LIVE_LINK_COLUMNS, ROTATION_GROUPS


def synthetic_weights(frames: int, seed: int = 0) -> np.ndarray:
    """(frames, 52) smooth weights in [0, 1]: each shape a raised sine of its own frequency and phase,
    some held at 0 (as a real take's unused shapes are)."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[:, None] / 60.0
    freq, phase = rng.uniform(0.2, 2.0, 52), rng.uniform(0, 2 * np.pi, 52)
    weights = 0.5 + 0.5 * np.sin(2 * np.pi * freq * t + phase)
    weights[:, rng.random(52) < 0.2] = 0.0
    return np.round(weights, 10)


def timecode(frame: int, fps: int, start: int = 12 * 3600 + 24 * 60 + 24) -> str:
    """``HH:MM:SS:FF.fff`` of frame ``frame`` after ``start`` seconds at an integer ``fps``."""
    whole = start + frame // fps
    return f"{whole // 3600:02d}:{whole // 60 % 60:02d}:{whole % 60:02d}:{frame % fps:02d}.000"


def write_take(path: Path, frames: int = 300, fps: int = 60, seed: int = 0, rotations: bool = True,
               weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Write a Live Link Face CSV of ``frames`` rows at ``fps``; returns (times s, weights (frames, 52),
    rotations group -> (frames, 3) radians) as written."""
    w = synthetic_weights(frames, seed) if weights is None else weights
    times = np.arange(frames) / fps
    t = times[:, None]
    angles = {"head": np.hstack([0.3 * np.sin(1.1 * t), 0.2 * np.sin(0.7 * t), 0.1 * np.sin(0.5 * t)]),
              "left_eye": np.hstack([0.25 * np.sin(2.3 * t), 0.15 * np.cos(1.9 * t), 0.0 * t]),
              "right_eye": np.hstack([0.25 * np.sin(2.3 * t), 0.15 * np.cos(1.9 * t), 0.0 * t])}
    angles = {k: np.round(v, 10) for k, v in angles.items()}
    columns = [c for c in LIVE_LINK_COLUMNS if rotations or c not in {n for g in ROTATION_GROUPS.values() for n in g}]
    lines = [",".join(columns)]
    for i in range(frames):
        row = [timecode(i, fps), "61"] + [f"{x:.10f}" for x in w[i]]
        if rotations:
            row += [f"{x:.10f}" for g in ROTATION_GROUPS for x in angles[g][i]]
        lines.append(",".join(row))
    path.write_text("\n".join(lines) + "\n")
    return times, w, (angles if rotations else {})


#: The expression of the test face: model weights by name (asymmetric browInnerUp halves).
TEST_EXPRESSION = {"jawOpen": 0.45, "eyeBlink_L": 0.7, "mouthSmile_R": 0.5, "browInnerUp_L": 0.2, "browInnerUp_R": 0.6,
                   "cheekPuff_L": 0.3, "cheekPuff_R": 0.3, "noseSneer_L": 0.25}


def shaped_asset(maps: dict | None = None, parts: bool = True):
    """The bundled model with a random identity and :data:`TEST_EXPRESSION`, its skin and parts
    carrying blendshapes (as the pipeline builds them): ``(asset, model, alpha, delta)``."""
    from facegeo.asset import Asset
    from facegeo.blendshapes import model_blendshapes
    from facegeo.model_files import load_model
    from facegeo.parts import load_parts, part_assets

    m = load_model()
    alpha = np.random.default_rng(3).normal(0.0, 0.7, m.n_id).astype(np.float32)
    delta = np.zeros(m.n_exp, np.float32)
    for name, value in TEST_EXPRESSION.items():
        delta[m.expression_names.index(name)] = value
    vertices = m.shape(alpha, delta).numpy()
    asset = Asset(vertices, m.triangles, m.uv, m.uv_triangles, maps=maps or {},
                  constants={} if maps else {"albedo": (0.7, 0.5, 0.45), "roughness": 0.5},
                  face_triangles=np.all(m.face_mask[m.triangles], axis=1), blendshapes=model_blendshapes(m, delta),
                  parts=part_assets(load_parts(m), m, alpha, delta, texture_size=32) if parts else [])
    return asset, m, alpha, delta
