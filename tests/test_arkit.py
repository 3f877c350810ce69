"""ARKit names, Live Link Face CSV takes, the rig's rotations and ``facegeo animate`` (issue 28)."""

from __future__ import annotations

import numpy as np
import pytest

from facegeo.cli import main
from facegeo.errors import InputError
from facegeo.export.animation import rotations, target_weights
from facegeo.arkit import ARKIT_NAMES, arkit_name, target_naming
from facegeo.arkit import ArkitTake
from facegeo.export.live_link import LIVE_LINK_COLUMNS, live_link_csv_text, read_live_link_csv
from arkit_support import shaped_asset, write_take


def test_ict_names_map_to_arkit(model):
    """ICT's 53 shapes cover 51 of ARKit's 52 names: the split browInnerUp and cheekPuff halves
    merge (both driven by one weight), tongueOut has no shape."""
    assert len(ARKIT_NAMES) == 52 == len(set(ARKIT_NAMES))
    assert arkit_name("eyeBlink_L") == "eyeBlinkLeft" and arkit_name("mouthSmile_R") == "mouthSmileRight"
    assert arkit_name("browInnerUp_R") == "browInnerUp" and arkit_name("jawOpen") == "jawOpen" and arkit_name("cheekRaiser_L") is None
    naming = target_naming(model.expression_names, "arkit")
    assert naming.names == tuple(n for n in ARKIT_NAMES if n != "tongueOut") and naming.missing == ("tongueOut",)
    names = model.expression_names
    row = naming.combine[naming.names.index("browInnerUp")]
    assert {names[j] for j in np.flatnonzero(row)} == {"browInnerUp_L", "browInnerUp_R"}
    delta = np.zeros(len(names))
    delta[names.index("browInnerUp_L")], delta[names.index("browInnerUp_R")] = 0.2, 0.6
    delta[names.index("eyeBlink_L")] = 0.7
    weights = naming.target_weights(delta)
    assert weights[naming.names.index("browInnerUp")] == pytest.approx(0.4)
    assert weights[naming.names.index("eyeBlinkLeft")] == pytest.approx(0.7)
    # an ARKit frame drives both halves, and nothing drives tongueOut
    frame = np.zeros(52)
    frame[ARKIT_NAMES.index("browInnerUp")], frame[ARKIT_NAMES.index("tongueOut")] = 0.5, 1.0
    model_weights = naming.model_from_arkit @ frame
    assert model_weights[names.index("browInnerUp_L")] == model_weights[names.index("browInnerUp_R")] == 0.5
    assert model_weights.sum() == pytest.approx(1.0)
    ict = target_naming(names, "ict")
    assert ict.names == tuple(names) and np.array_equal(ict.combine, np.eye(len(names)))
    with pytest.raises(InputError, match="ARKit counterpart"):
        target_naming(["jawOpen", "smirk"], "arkit")
    with pytest.raises(InputError, match="one of arkit, ict"):
        target_naming(names, "maya")


def test_take_round_trip(tmp_path):
    csv = tmp_path / "take.csv"
    times, weights, angles = write_take(csv, frames=300, fps=60)
    take = read_live_link_csv(csv, fps=60)
    assert take.n_frames == 300 and take.fps == 60
    np.testing.assert_allclose(take.times, times, atol=1e-9)
    np.testing.assert_allclose(take.weights, weights, atol=1e-7)
    assert set(take.rotations) == {"head", "left_eye", "right_eye"}
    np.testing.assert_allclose(take.rotations["head"], angles["head"], atol=1e-12)
    # read at 30 fps, its frame numbers (up to 59) are not valid time codes: refused, not misread
    with pytest.raises(InputError, match="row 32, column Timecode: expected .* frames below 30"):
        read_live_link_csv(csv, fps=30)
    times30, _, _ = write_take(csv, frames=100, fps=30)
    np.testing.assert_allclose(read_live_link_csv(csv, fps=30).times, times30, atol=1e-9)
    write_take(csv, frames=4, rotations=False)
    assert read_live_link_csv(csv).rotations == {}


def test_written_take_reads_back_the_same(tmp_path):
    """live_link_csv_text: weights exact (float32), times to 1e-6 s, rotations exact; with and
    without the rotation columns; the time code of one row spelled out."""
    rng = np.random.default_rng(3)
    n, fps = 50, 30.0
    weights = rng.random((n, 52)).astype(np.float32)
    weights[0, :2] = (0.0, 1.0)
    angles = {g: rng.uniform(-3.0, 3.0, (n, 3)) for g in ("head", "left_eye", "right_eye")}
    take = ArkitTake("<take>", fps, np.arange(n) / fps, weights, angles)
    csv = tmp_path / "take.csv"
    text = live_link_csv_text(take)
    lines = text.splitlines()
    assert lines[0] == ",".join(LIVE_LINK_COLUMNS) and len(lines) == n + 1
    assert lines[1].startswith("00:00:00:00.000,61,0,1,")
    csv.write_text(text)
    back = read_live_link_csv(csv, fps=fps)
    assert back.n_frames == n and back.weights.dtype == np.float32
    assert np.array_equal(back.weights, weights)
    np.testing.assert_allclose(back.times, take.times, rtol=0, atol=1e-6)
    assert set(back.rotations) == set(angles)
    for g, a in angles.items():
        np.testing.assert_allclose(back.rotations[g], a, rtol=0, atol=1e-9)
    # frame 61 at 30 fps (2 s + 1 frame), with an hour of time code before it
    long = ArkitTake("<take>", fps, np.arange(62) / fps, rng.random((62, 52)).astype(np.float32))
    rows = live_link_csv_text(long, timecode_start_s=3600 + 60).splitlines()
    assert rows[62].startswith("01:01:02:01.000,52,")
    assert rows[0] == ",".join(LIVE_LINK_COLUMNS[:54])
    csv.write_text("\n".join(rows) + "\n")
    back = read_live_link_csv(csv, fps=fps)
    assert back.rotations == {} and np.array_equal(back.weights, long.weights)
    np.testing.assert_allclose(back.times, long.times, rtol=0, atol=1e-6)
    # the head alone: 55 values a row; a sub-frame time survives to a thousandth of a frame
    head = ArkitTake("<take>", 60.0, np.array([0.0, 0.0101, 1.5]), weights[:3], {"head": angles["head"][:3]})
    text = live_link_csv_text(head)
    assert text.splitlines()[2].startswith("00:00:00:00.606,55,")
    csv.write_text(text)
    back = read_live_link_csv(csv, fps=60)
    assert set(back.rotations) == {"head"}
    np.testing.assert_allclose(back.times, head.times, rtol=0, atol=0.5e-3 / 60)


def test_a_real_header_and_time_code(tmp_path):
    """Live Link Face's own header and its sub-frame time codes (HH:MM:SS:FF.fff)."""
    csv = tmp_path / "t.csv"
    row = ",".join(["0.1"] * 52 + ["0"] * 9)
    csv.write_text(",".join(LIVE_LINK_COLUMNS) + "\n" + f"12:24:24:19.960,61,{row}\n12:24:24:21.959,61,{row}\n")
    take = read_live_link_csv(csv)
    assert take.times[1] == pytest.approx((21.959 - 19.960) / 60)


def _bad(tmp_path, edit):
    """Write a 3-frame take, apply ``edit(lines) -> lines`` and read it."""
    csv = tmp_path / "bad.csv"
    write_take(csv, frames=3)
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(edit(lines)) + "\n")
    return csv


def _cell(lines, row, column, value):
    header = lines[0].split(",")
    cells = lines[row - 1].split(",")
    cells[header.index(column)] = value
    lines[row - 1] = ",".join(cells)
    return lines


@pytest.mark.parametrize("edit, where", [
    (lambda ls: [ls[0].replace("JawOpen,", "")] + [",".join(c for i, c in enumerate(l.split(",")) if i != ls[0].split(",").index("JawOpen")) for l in ls[1:]],
     "row 1, column JawOpen"),
    (lambda ls: [ls[0].replace("JawOpen", "JawOpenWide")] + ls[1:], "row 1, column 20"),
    (lambda ls: [ls[0].replace("JawOpen", "jawOpen")] + ls[1:], "row 1, column 20"),
    (lambda ls: _cell(ls, 3, "MouthFunnel", "abc"), "row 3, column MouthFunnel"),
    (lambda ls: _cell(ls, 2, "EyeBlinkLeft", "nan"), "row 2, column EyeBlinkLeft"),
    (lambda ls: _cell(ls, 4, "CheekPuff", "1.2"), "row 4, column CheekPuff"),
    (lambda ls: _cell(ls, 3, "HeadYaw", "7"), "row 3, column HeadYaw"),
    (lambda ls: _cell(ls, 3, "Timecode", "12:24:24"), "row 3, column Timecode"),
    (lambda ls: _cell(ls, 3, "Timecode", "12:24:24:75.000"), "row 3, column Timecode"),
    (lambda ls: _cell(_cell(ls, 3, "Timecode", "12:24:24:05.000"), 4, "Timecode", "12:24:24:04.000"), "row 4, column Timecode"),
    (lambda ls: _cell(ls, 2, "BlendShapeCount", "6.5"), "row 2, column BlendShapeCount"),
    (lambda ls: ls[:2] + [ls[2] + ",0.5"] + ls[3:], "row 3"),
    (lambda ls: ls[:1], "row 2"),
    (lambda ls: [], "row 1"),
    (lambda ls: [ls[0].replace(",RightEyeRoll", "")] + [l.rsplit(",", 1)[0] for l in ls[1:]], "row 1, column RightEyeRoll"),
    (lambda ls: [line.replace(",", ";") for line in ls], "row 1"),
])
def test_bad_takes_name_the_file_row_and_column(tmp_path, edit, where):
    csv = _bad(tmp_path, edit)
    with pytest.raises(InputError) as info:
        read_live_link_csv(csv)
    message = str(info.value)
    assert message.startswith(str(csv)) and f": {where}:" in message, message


def test_clamping_is_asked_for(tmp_path):
    csv = _bad(tmp_path, lambda ls: _cell(_cell(ls, 2, "JawOpen", "1.04"), 3, "MouthClose", "-0.01"))
    with pytest.raises(InputError, match="or --clamp"):
        read_live_link_csv(csv)
    take = read_live_link_csv(csv, clamp=True)
    assert take.weights[0, ARKIT_NAMES.index("jawOpen")] == 1.0 and take.weights[1, ARKIT_NAMES.index("mouthClose")] == 0.0
    assert len(take.notes) == 1 and "2 weights outside [0, 1] clamped" in take.notes[0] and "row 2, column JawOpen" in take.notes[0]
    with pytest.raises(InputError, match="fps"):
        read_live_link_csv(csv, fps=0)


def test_rotation_signs():
    """Live Link Face's signs (measured on a recorded take): a negative yaw turns the gaze towards
    the subject's left (+X), a positive pitch looks down (−Y); no turn is the identity."""
    from scipy.spatial.transform import Rotation

    forward = np.array([0.0, 0.0, 1.0])
    q = rotations(np.array([[-0.3, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.25]]))
    gaze = Rotation.from_quat(q).apply(forward)
    assert gaze[0, 0] > 0.29 and gaze[1, 1] < -0.19
    np.testing.assert_allclose(q[2], [0, 0, 0, 1], atol=1e-12)
    up = Rotation.from_quat(q[3]).apply([0.0, 1.0, 0.0])
    assert up[0] > 0.24  # roll: the top of the head towards the subject's left


def test_a_missing_column_and_another_separator_are_said_as_such(tmp_path):
    def drop(lines):  # the two columns taken out of every row
        header = lines[0].split(",")
        return [",".join(c for c, name in zip(line.split(","), header) if name not in ("JawOpen", "MouthClose")) for line in lines]

    with pytest.raises(InputError, match=r": row 1, column JawOpen: expected Timecode, BlendShapeCount and every Live Link Face "
                                         r"blendshape column, found 2 missing: JawOpen, MouthClose$"):
        read_live_link_csv(_bad(tmp_path, drop))
    with pytest.raises(InputError, match=r": row 1: expected comma-separated columns, found ';'-separated ones$"):
        read_live_link_csv(_bad(tmp_path, lambda ls: [line.replace(",", ";") for line in ls]))


def test_take_weights_to_targets(model, tmp_path):
    csv = tmp_path / "take.csv"
    _, weights, _ = write_take(csv, frames=10)
    take = read_live_link_csv(csv)
    for naming_name in ("arkit", "ict"):
        naming = target_naming(model.expression_names, naming_name)
        frames = target_weights(take, naming)
        for t, name in enumerate(naming.names):
            source = name if naming_name == "arkit" else (
                "browInnerUp" if name.startswith("browInnerUp") else "cheekPuff" if name.startswith("cheekPuff")
                else name.replace("_L", "Left").replace("_R", "Right"))
            np.testing.assert_allclose(frames[:, t], weights[:, ARKIT_NAMES.index(source)], atol=1e-7)


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    from facegeo.export.asset_io import save_asset

    asset, *_ = shaped_asset()
    return save_asset(asset, tmp_path_factory.mktemp("asset") / "a")


def test_animate_command(saved, tmp_path, capsys):
    csv = tmp_path / "take.csv"
    write_take(csv, frames=40)
    for suffix, parts in (("glb", "full"), ("usdz", "head")):
        out = tmp_path / f"anim.{suffix}"
        assert main(["animate", str(saved), "--arkit-csv", str(csv), "-o", str(out), "--parts", parts]) == 0, capsys.readouterr().err
        assert out.is_file()
        printed = capsys.readouterr().out
        assert "40 frames" in printed and "TongueOut: the model has no such shape" in printed
        assert ("no eyeballs; the eye rotations are not written" in printed) == (parts == "head")


def test_animate_reads_the_rate_of_a_take_that_facegeo_track_wrote(saved, tmp_path, capsys):
    # track's take.csv counts the Timecode's frames at the clip's rate (30 here), which the CSV does
    # not say: read at Live Link Face's 60 it played twice as fast, jumping at each second
    import json

    csv = tmp_path / "take.csv"
    write_take(csv, frames=45, fps=30)
    out = tmp_path / "anim.glb"
    (tmp_path / "track.json").write_text(json.dumps({"source": "clip.mp4", "fps": 30.0, "frames_tracked": 45}))
    assert main(["animate", str(saved), "--arkit-csv", str(csv), "-o", str(out)]) == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    assert "45 frames, 1.47 s at 30 fps time code" in printed and "time code rate 30 fps, the tracked clip's" in printed
    assert main(["animate", str(saved), "--arkit-csv", str(csv), "-o", str(out), "--fps", "60"]) == 0  # the option wins
    assert "at 60 fps time code" in capsys.readouterr().out
    (tmp_path / "track.json").write_text(json.dumps({"fps": 0, "frames_tracked": 45}))
    assert main(["animate", str(saved), "--arkit-csv", str(csv), "-o", str(out)]) == 2
    assert "track.json: fps: expected the tracked clip's frames per second (> 0), found 0" in capsys.readouterr().err
    (tmp_path / "track.json").write_text("{}")  # not facegeo track's: Live Link Face's default
    assert main(["animate", str(saved), "--arkit-csv", str(csv), "-o", str(out)]) == 0
    assert "at 60 fps time code" in capsys.readouterr().out


def test_animate_command_errors_leave_nothing(saved, tmp_path, capsys):
    csv = _bad(tmp_path, lambda ls: _cell(ls, 3, "JawOpen", "x"))
    out = tmp_path / "anim.glb"
    assert main(["animate", str(saved), "--arkit-csv", str(csv), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "row 3, column JawOpen" in err and str(csv) in err
    assert main(["animate", str(saved), "--arkit-csv", str(csv), "-o", str(tmp_path / "anim.obj")]) == 2
    assert "suffix" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob(".facegeo-tmp*"))


def test_export_command_blendshape_options(saved, tmp_path, capsys):
    import pygltflib

    out = tmp_path / "f.glb"
    assert main(["export", str(saved), "-o", str(out), "--blendshape-names", "ict", "--parts", "head"]) == 0, capsys.readouterr().err
    doc = pygltflib.GLTF2().load_binary(str(out))
    assert doc.meshes[0].extras["targetNames"][0] == "browDown_L"
    assert main(["export", str(saved), "-o", str(out), "--blendshapes", "none", "--parts", "head"]) == 0
    doc = pygltflib.GLTF2().load_binary(str(out))
    assert not doc.meshes[0].primitives[0].targets
