"""Blendshapes in the exported files (issue 28): glTF morph targets, UsdSkel blend shapes, the asset
folder, and the animation of a Live Link Face take, checked by reading the files back."""

from __future__ import annotations

import numpy as np
import pygltflib
import pytest

from facegeo.blendshapes import Blendshapes
from facegeo.errors import InputError
from facegeo.arkit import ARKIT_NAMES, target_naming
from facegeo.export.asset_io import load_asset, save_asset
from facegeo.export.gltf import GltfValidatorMissing, find_gltf_validator, validate_glb, write_glb
from facegeo.export.live_link import read_live_link_csv
from facegeo.export.subdivision import subdivide_arrays
from facegeo.export.usd import skel_points, validate_usd, write_usd
from arkit_support import shaped_asset, write_take

_DTYPES = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5122: np.int16, 5120: np.int8}
_NORMALIZED = {5122: 32767.0, 5120: 127.0, 5123: 65535.0}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def read_glb(path):
    """``(doc, accessor)``: ``accessor(i)`` decodes accessor i as float64 (count, width), dense
    data, sparse substitution and normalisation included, as a glTF loader does."""
    doc = pygltflib.GLTF2().load_binary(str(path))
    blob = doc.binary_blob()

    def raw(view, offset, component, count, width):
        start = doc.bufferViews[view].byteOffset + (offset or 0)
        return np.frombuffer(blob, dtype=_DTYPES[component], count=count * width, offset=start).reshape(count, width)

    def accessor(index):
        acc = doc.accessors[index]
        width = _WIDTH[acc.type]
        if acc.bufferView is None:
            out = np.zeros((acc.count, width))
        else:
            out = raw(acc.bufferView, acc.byteOffset, acc.componentType, acc.count, width).astype(np.float64)
        if acc.sparse is not None:
            s = acc.sparse
            rows = raw(s.indices.bufferView, s.indices.byteOffset, s.indices.componentType, s.count, 1)[:, 0]
            assert np.all(np.diff(rows.astype(np.int64)) > 0), "sparse indices must increase"
            out[rows] = raw(s.values.bufferView, s.values.byteOffset, acc.componentType, s.count, width)
        if acc.normalized:
            out = np.maximum(out / _NORMALIZED[acc.componentType], -1.0)
        return out

    return doc, accessor


def _mesh(doc, accessor, name):
    """A mesh's wedge positions (mm), triangles, its targets' POSITION deltas (T, W, 3) mm and
    NORMAL deltas, its weights and target names."""
    mesh = next(m for m in doc.meshes if m.name == name)
    prim = mesh.primitives[0]
    positions = accessor(prim.attributes.POSITION) * 1000.0
    triangles = accessor(prim.indices).reshape(-1, 3).astype(np.int64)
    targets = prim.targets or []
    deltas = np.stack([accessor(t["POSITION"]) * 1000.0 for t in targets]) if targets else None
    normals = np.stack([accessor(t["NORMAL"]) for t in targets]) if targets else None
    return positions, triangles, deltas, normals, mesh.weights, (mesh.extras or {}).get("targetNames")


def _nearest(points, queries):
    """Index of the nearest point to each query."""
    from scipy.spatial import cKDTree

    return cKDTree(points).query(queries)[1]


@pytest.fixture(scope="module")
def face():
    return shaped_asset()


@pytest.fixture(scope="module")
def glb(face, tmp_path_factory):
    asset, *_ = face
    return write_glb(asset, tmp_path_factory.mktemp("glb") / "face.glb")


def test_glb_targets_names_weights_and_pose(face, glb):
    """Every moving mesh has the 51 ARKit targets in the same order, weights = the fitted
    expression, and base + Σ w·target is the posed mesh (to the quantisation step, 31 µm per
    target); at weights 0 it is the identity's neutral mesh."""
    asset, m, alpha, delta = face
    doc, accessor = read_glb(glb)
    naming = target_naming(m.expression_names, "arkit")
    assert len(naming.names) == 51 and "tongueOut" not in naming.names and naming.missing == ("tongueOut",)
    assert doc.extensionsRequired == ["KHR_mesh_quantization"]
    assert doc.asset.extras["blendshapeNames"] == "arkit"
    assert any("tongueOut" in note for note in doc.asset.extras["blendshapeNotes"])
    assert any(note.startswith("browInnerUp:") for note in doc.asset.extras["blendshapeNotes"])  # 0.2 / 0.6 averaged
    expected_weights = naming.target_weights(delta)
    projected = naming.combine.T @ expected_weights  # the model weights the file shows
    shown = {"face": m.shape(alpha, projected).numpy()}
    shown.update({p.name: v for p, v in zip(asset.parts, _part_vertices(m, alpha, projected))})
    neutral = {"face": m.shape(alpha).numpy()}
    neutral.update({p.name: v for p, v in zip(asset.parts, _part_vertices(m, alpha, None))})
    with_targets = [mesh.name for mesh in doc.meshes if mesh.primitives[0].targets]
    assert with_targets == ["face", "eye_sockets", "mouth_socket", "gums_tongue", "teeth"]  # eyeballs move with no shape
    for name in with_targets:
        positions, triangles, deltas, normals, weights, names = _mesh(doc, accessor, name)
        assert names == list(naming.names)
        np.testing.assert_allclose(weights, expected_weights, atol=1e-7)
        # the base is the neutral mesh: compare wedge positions with the neutral vertices they copy
        vertex = _nearest(neutral[name], positions[:: max(1, len(positions) // 400)])
        np.testing.assert_allclose(positions[:: max(1, len(positions) // 400)], neutral[name][vertex], atol=1e-3)
        posed = positions + np.tensordot(np.asarray(weights), deltas, axes=1)
        wedge_vertex = _nearest(neutral[name], positions) if name != "face" else None
        if wedge_vertex is not None:
            error = np.abs(posed - shown[name][wedge_vertex]).max()
            assert error < 0.1, f"{name}: {error} mm"
    # the skin: wedge -> vertex through the triangles (same corner order as the model's)
    positions, triangles, deltas, _, weights, _ = _mesh(doc, accessor, "face")
    wedge_vertex = np.empty(len(positions), np.int64)
    wedge_vertex[triangles.ravel()] = m.triangles.ravel()
    posed = positions + np.tensordot(np.asarray(weights), deltas, axes=1)
    assert np.abs(positions - neutral["face"][wedge_vertex]).max() < 1e-3
    assert np.abs(posed - shown["face"][wedge_vertex]).max() < 0.1
    assert np.abs(shown["face"] - asset.vertices).max() > 0.5  # the brows' halves differ: ARKit's one weight shows


def _part_vertices(m, alpha, delta):
    from facegeo.parts import load_parts, part_vertices

    return list(part_vertices(load_parts(m), m, alpha, delta).values())


def test_left_is_the_subjects_left_by_geometry(face, glb):
    """+X is the subject's left (iBUG 36, the outer corner of the subject's right eye, is at
    x < 0), and the file's eyeBlinkLeft closes the eye at x > 0 (mouthSmileLeft: the mouth
    corner at x > 0)."""
    asset, m, *_ = face
    assert m.mean_shape[m.landmark_indices[36], 0] < 0 < m.mean_shape[m.landmark_indices[45], 0]
    doc, accessor = read_glb(glb)
    positions, _, deltas, _, _, names = _mesh(doc, accessor, "face")
    for name, down in (("eyeBlinkLeft", True), ("mouthSmileLeft", False), ("eyeBlinkRight", True)):
        d = deltas[names.index(name)]
        size = np.linalg.norm(d, axis=1)
        moved = size > 0.3 * size.max()
        side = np.sign(np.average(positions[moved, 0], weights=size[moved]))
        assert side == (1 if name.endswith("Left") else -1), name
        if down:
            assert d[size.argmax(), 1] < -5.0  # the upper lid comes down (mm)


def test_glb_validates(face, glb, tmp_path):
    try:
        find_gltf_validator()
    except GltfValidatorMissing as exc:
        pytest.skip(f"Khronos glTF-Validator not available: {exc}")
    issues = validate_glb(glb)["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]
    asset, *_ = face
    take = tmp_path / "take.csv"
    write_take(take, frames=30)
    animated = write_glb(asset, tmp_path / "anim.glb", blendshapes="ict", animation=read_live_link_csv(take))
    issues = validate_glb(animated)["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


def test_targets_follow_the_subdivision(face, tmp_path):
    """At --subdiv 1 a target deforms the exported (subdivided) mesh: base + Σ w·target is the
    subdivided posed mesh (Loop subdivision is linear), to the quantisation step."""
    asset, m, alpha, delta = face
    head = asset.select("head")
    doc, accessor = read_glb(write_glb(head, tmp_path / "s.glb", level=1, blendshapes="ict"))
    positions, triangles, deltas, _, weights, names = _mesh(doc, accessor, "face")
    assert names == list(m.expression_names)
    v_posed, f_posed, _, _ = subdivide_arrays(asset.vertices, asset.triangles, None, None, 1)
    v_neutral, _, _, _ = subdivide_arrays(asset.neutral_vertices(), asset.triangles, None, None, 1)
    wedge_vertex = np.empty(len(positions), np.int64)
    wedge_vertex[triangles.ravel()] = f_posed.ravel()
    assert np.abs(positions - v_neutral[wedge_vertex]).max() < 1e-3
    posed = positions + np.tensordot(np.asarray(weights), deltas, axes=1)
    assert np.abs(posed - v_posed[wedge_vertex]).max() < 0.1
    jaw = deltas[names.index("jawOpen")]
    assert jaw[:, 1].min() < -20.0  # the chin drops by more than 2 cm at weight 1


def test_static_when_asked(face, tmp_path):
    asset, *_ = face
    doc, accessor = read_glb(write_glb(asset, tmp_path / "n.glb", blendshapes=None))
    assert all(not m.primitives[0].targets and not m.weights for m in doc.meshes)
    assert not doc.extensionsRequired
    positions, triangles, *_ = _mesh(doc, accessor, "face")
    assert np.abs(positions[triangles].reshape(-1, 3) - asset.vertices[asset.triangles].reshape(-1, 3)).max() < 1e-3
    with pytest.raises(InputError, match="blendshape"):
        write_glb(asset, tmp_path / "x.glb", blendshapes="fancy")


@pytest.mark.parametrize("naming", ["ict", "arkit"])
def test_usdskel_reproduces_the_posed_mesh(face, tmp_path, naming):
    """UsdSkel's own evaluation (UsdSkel.Cache, BlendShapeQuery, skinning) of the neutral points
    and the fitted weights is the exported posed mesh to 1e-4 mm: with ICT names the fit's own
    mesh (the asset's vertices), with ARKit names the fit with browInnerUp's halves averaged."""
    asset, m, alpha, delta = face
    path = write_usd(asset, tmp_path / "face.usdc", blendshapes=naming)
    assert [e for e in validate_usd(path) if e[0] == "Error"] == []
    points = skel_points(path)
    names = target_naming(m.expression_names, naming)
    projected = names.combine.T @ names.target_weights(delta)
    expected = {"/face/mesh": m.shape(alpha, projected).numpy().astype(np.float64)}
    expected.update({f"/face/parts/{p.name}": v.astype(np.float64) for p, v in zip(asset.parts, _part_vertices(m, alpha, projected))})
    assert set(points) == set(expected)
    for prim, want in expected.items():
        assert np.abs(points[prim] - want).max() < 1e-4, prim
    if naming == "ict":
        assert np.abs(points["/face/mesh"] - asset.vertices).max() < 1e-4
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.Open(str(path))
    assert stage.GetDefaultPrim().IsA(UsdSkel.Root)
    binding = UsdSkel.BindingAPI(stage.GetPrimAtPath("/face/mesh"))
    assert list(binding.GetBlendShapesAttr().Get()) == list(names.names)
    shape = UsdSkel.BlendShape(stage.GetPrimAtPath(f"/face/mesh/{names.names[0]}"))
    assert 0 < len(shape.GetPointIndicesAttr().Get()) < len(asset.vertices)  # sparse
    neutral = np.array(stage.GetPrimAtPath("/face/mesh").GetAttribute("points").Get())
    assert np.abs(neutral - m.shape(alpha).numpy()).max() < 1e-3


def test_usdskel_at_subdivision_with_displacement(face, tmp_path):
    """At --subdiv 1 with a baked displacement the blend shapes move the displaced neutral by the
    subdivided expression: UsdSkel's points minus the file's points = S·(posed − neutral)."""
    from test_export_support import synthetic_maps

    asset, m, alpha, delta = face
    head = asset.select("head")
    head.maps = {"displacement": synthetic_maps(32)["displacement"]}
    path = write_usd(head, tmp_path / "d.usdc", level=1, blendshapes="ict")
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    base = np.array(stage.GetPrimAtPath("/face/mesh").GetAttribute("points").Get(), dtype=np.float64)
    moved = skel_points(path)["/face/mesh"] - base
    v_posed, _, _, _ = subdivide_arrays(asset.vertices, asset.triangles, None, None, 1)
    v_neutral, _, _, _ = subdivide_arrays(asset.neutral_vertices(), asset.triangles, None, None, 1)
    assert np.abs(moved - (v_posed - v_neutral)).max() < 1e-4


def test_asset_folder_keeps_the_blendshapes(face, tmp_path):
    asset, *_ = face
    folder = save_asset(asset, tmp_path / "a")
    assert (folder / "blendshapes.npz").is_file()
    back = load_asset(folder)
    np.testing.assert_array_equal(back.blendshapes.deltas, asset.blendshapes.deltas)  # float16 in the file: lossless here
    np.testing.assert_array_equal(back.blendshapes.weights, asset.blendshapes.weights)
    assert back.blendshapes.names == asset.blendshapes.names
    for p, q in zip(back.parts, asset.parts):
        assert (p.blendshapes is None) == (q.blendshapes is None)
        if q.blendshapes is not None:
            np.testing.assert_array_equal(p.blendshapes.deltas, q.blendshapes.deltas)
    assert np.abs(back.neutral_vertices() - asset.neutral_vertices()).max() < 1e-3
    face_only = back.select("face")
    assert face_only.blendshapes.deltas.shape[1] == len(face_only.vertices)


def test_the_blendshapes_file_made_once_is_written_again_only_for_the_same_shapes(face, tmp_path):
    """The last blendshapes.npz is kept (a batch worker's photos share their model's shapes): the
    same shapes give the same bytes, other deltas their own file, read back as they are."""
    from dataclasses import replace

    asset, *_ = face
    first, again = (save_asset(asset, tmp_path / name) / "blendshapes.npz" for name in ("a", "b"))
    assert first.read_bytes() == again.read_bytes()
    deltas = asset.blendshapes.deltas.copy()
    deltas[0] *= 2.0
    changed = replace(asset, blendshapes=replace(asset.blendshapes, deltas=deltas))
    other = save_asset(changed, tmp_path / "c")
    assert (other / "blendshapes.npz").read_bytes() != first.read_bytes()
    np.testing.assert_array_equal(load_asset(other).blendshapes.deltas, deltas)
    np.testing.assert_array_equal(load_asset(save_asset(asset, tmp_path / "d")).blendshapes.deltas, asset.blendshapes.deltas)


@pytest.mark.parametrize("damage", ["truncated", "corrupt member"])
def test_a_damaged_blendshapes_file_is_named_in_one_error(face, tmp_path, damage):
    asset, *_ = face
    folder = save_asset(asset, tmp_path / "a")
    path = folder / "blendshapes.npz"
    data = bytearray(path.read_bytes())
    if damage == "truncated":
        data = data[:300]
    else:  # the zip's directory intact, a member's bytes not (its CRC fails on reading)
        data[len(data) // 2:len(data) // 2 + 200] = bytes(200)
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"blendshapes\.npz: blendshapes: expected an \.npz file written by facegeo, found BadZipFile"):
        load_asset(folder)


def test_mismatched_blendshapes_are_refused(face):
    asset, *_ = face
    with pytest.raises(InputError, match="blendshapes.deltas"):
        asset.select("head").__class__(asset.vertices[:10], np.array([[0, 1, 2]]), asset.uv, np.array([[0, 1, 2]]),
                                       blendshapes=asset.blendshapes)
    bad = Blendshapes(asset.blendshapes.names, asset.blendshapes.deltas, asset.blendshapes.weights * 0.5)
    with pytest.raises(InputError, match="same blendshape names and weights"):
        asset.__class__(asset.vertices, asset.triangles, asset.uv, asset.uv_triangles, blendshapes=bad, parts=asset.parts)


def test_animated_files_key_the_takes_weights(face, tmp_path):
    """A 300-frame take animates the glb and the USD: the keyed weights at every frame equal the
    CSV's after the name mapping (to 1e-6), the head and eyes get rotation keys, and UsdSkel's
    evaluation at a frame is the neutral mesh posed by that frame's weights, turned by the head."""
    from scipy.spatial.transform import Rotation

    asset, m, alpha, delta = face
    csv = tmp_path / "take.csv"
    times, weights, angles = write_take(csv, frames=300)
    take = read_live_link_csv(csv)
    np.testing.assert_allclose(take.times, times, atol=1e-9)
    naming = target_naming(m.expression_names, "arkit")
    expected = weights[:, [ARKIT_NAMES.index(n) for n in naming.names]]

    doc, accessor = read_glb(write_glb(asset, tmp_path / "a.glb", animation=take))
    (animation,) = doc.animations
    nodes = {n.name: i for i, n in enumerate(doc.nodes)}
    channels = {(doc.nodes[c.target.node].name, c.target.path): animation.samplers[c.sampler] for c in animation.channels}
    assert {k for k in channels if k[1] == "weights"} == {(n, "weights") for n in ("face", "eye_sockets", "mouth_socket", "gums_tongue", "teeth")}
    sampler = channels[("face", "weights")]
    np.testing.assert_allclose(accessor(sampler.input)[:, 0], times, atol=1e-6)
    keyed = accessor(sampler.output).reshape(300, -1)
    assert np.abs(keyed - expected).max() < 1e-6
    head = accessor(channels[("head", "rotation")].output)
    want = Rotation.from_euler("YXZ", np.stack([-angles["head"][:, 0], angles["head"][:, 1], -angles["head"][:, 2]], 1)).as_quat()
    assert np.abs(np.abs(np.sum(head * want, axis=1)) - 1).max() < 1e-6
    assert ("eye_left", "rotation") in channels and ("eye_right", "rotation") in channels
    assert doc.nodes[nodes["eye_left"]].translation[0] > 0 > doc.nodes[nodes["eye_right"]].translation[0]
    assert doc.scenes[0].nodes == [nodes["head"]]

    path = write_usd(asset, tmp_path / "a.usdc", animation=take)
    assert [e for e in validate_usd(path) if e[0] == "Error"] == []
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.Open(str(path))
    anim = UsdSkel.Animation(stage.GetPrimAtPath("/face/animation"))
    samples = anim.GetBlendShapeWeightsAttr().GetTimeSamples()
    assert len(samples) == 300 and stage.GetTimeCodesPerSecond() == 60
    usd_weights = np.array([anim.GetBlendShapeWeightsAttr().Get(t) for t in samples])
    assert np.abs(usd_weights - expected).max() < 1e-6
    k = 137
    points = skel_points(path, samples[k])["/face/mesh"]
    model_weights = naming.combine.T @ expected[k]
    rotation = Rotation.from_quat(want[k]).as_matrix()
    assert np.abs(points - m.shape(alpha, model_weights).numpy() @ rotation.T).max() < 1e-3


def test_animation_needs_blendshapes(face, tmp_path):
    asset, *_ = face
    csv = tmp_path / "take.csv"
    write_take(csv, frames=5)
    take = read_live_link_csv(csv)
    with pytest.raises(InputError, match="blendshapes"):
        write_glb(asset, tmp_path / "x.glb", blendshapes=None, animation=take)
    plain = asset.__class__(asset.vertices, asset.triangles, asset.uv, asset.uv_triangles, constants={"roughness": 0.5})
    with pytest.raises(InputError, match="blendshapes"):
        write_usd(plain, tmp_path / "x.usda", animation=take)
    assert not list(tmp_path.glob("x.*"))


def test_export_scenes_shares_the_scene(face, tmp_path):
    """Several formats at once (what facegeo reconstruct writes) give the files one call per format
    gives: the same glb bytes, the same UsdSkel evaluation; a bad output is refused first."""
    from facegeo.export.writers import export_asset, export_scenes

    asset, *_ = face
    head = asset.select("head")
    glb, usdc = export_scenes(head, [(tmp_path / "a.glb", None), (tmp_path / "a", "usdc")])
    assert usdc == tmp_path / "a.usdc"
    assert glb.read_bytes() == export_asset(head, tmp_path / "b.glb").read_bytes()
    alone = export_asset(head, tmp_path / "b.usdc")
    np.testing.assert_array_equal(skel_points(usdc)["/face/mesh"], skel_points(alone)["/face/mesh"])
    with pytest.raises(InputError, match="displacement"):
        export_scenes(head, [(tmp_path / "c.usdc", None), (tmp_path / "c.glb", None)], displacement="texture")
    assert not list(tmp_path.glob("c.*"))
