"""The ``facegeo realy`` subcommand (argparse, declared in facegeo.commands.realy)."""

from __future__ import annotations

import argparse
import json
import shutil

import pytest

from facegeo.errors import FacegeoError
from facegeo.commands.arguments import add_commands
from facegeo.commands.realy import COMMANDS
from facegeo.eval.realy_report import OUTPUT_FILES
from realy_synthetic import make_dataset


def run(args, capsys):
    """What facegeo.cli.main does with a registered subcommand: run, print FacegeoError, exit 2."""
    parser = argparse.ArgumentParser(prog="facegeo")
    add_commands(parser.add_subparsers(dest="command", required=True), COMMANDS)
    ns = parser.parse_args([str(a) for a in args])
    try:
        ns.run(ns)
        code = 0
    except FacegeoError as exc:
        print(f"facegeo: error: {exc}", file=__import__("sys").stderr)
        code = 2
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = make_dataset(tmp_path_factory.mktemp("realy_cli"), 1, seed=0, subdivisions=0)
    return d


def test_cli_writes_the_four_files(data, tmp_path, capsys):
    out = tmp_path / "eval"
    code, stdout, err = run(["realy", data.pred_dir, "--realy-root", data.realy_root, "-o", out], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES)
    assert (out / "REALY_error.txt").read_text().startswith("1\t\t0.8506133\t1.5193866\t3.7678127\t1.9261925")
    assert "| mean ± std (mm) |" in stdout and "evaluated 1 prediction(s)" in stdout


def test_cli_errors_exit_2_with_one_line(data, tmp_path, capsys):
    code, _, err = run(["realy", data.pred_dir, "--realy-root", tmp_path], capsys)
    assert code == 2 and "REALY_HIFI3D_keypoints" in err and "Traceback" not in err
    code, _, err = run(["realy", data.pred_dir, "--realy-root", data.realy_root, "--topology", "BFM09"], capsys)
    assert code == 2 and "keypoint file of topology BFM09" in err
    code, _, err = run(["realy", data.pred_dir, "--realy-root", data.realy_root, "--workers", "0"], capsys)
    assert code == 2 and "--workers" in err
    empty = tmp_path / "empty_pred"
    empty.mkdir()
    code, _, err = run(["realy", empty, "--realy-root", data.realy_root], capsys)
    assert code == 2 and "no .obj files" in err
    with pytest.raises(SystemExit):  # argparse: --topology and --keypoints exclude each other
        run(["realy", data.pred_dir, "--topology", "X", "--keypoints", "k.txt"], capsys)


def test_cli_keypoints_file_and_missing_subject(data, tmp_path, capsys):
    pred = tmp_path / "pred"
    shutil.copytree(data.pred_dir, pred)
    shutil.copyfile(pred / "1.obj", pred / "2.obj")  # subject 2 has no REALY data
    kp = data.realy_root / "data" / "ICT-FaceKit.txt"
    code, _, err = run(["realy", pred, "--realy-root", data.realy_root, "--keypoints", kp], capsys)
    assert code == 2 and "REALY_HIFI3D_keypoints/2.obj" in err and "subject 2" in err


def test_cli_speed_knobs_are_checked_and_written(data, tmp_path, capsys):
    code, _, err = run(["realy", data.pred_dir, "--realy-root", data.realy_root, "--solver-rtol", "-1"], capsys)
    assert code == 2 and "solver_rtol" in err and len(err.strip().splitlines()) == 1
    out = tmp_path / "loose"
    code, stdout, err = run(["realy", data.pred_dir, "--realy-root", data.realy_root, "-o", out, "--workers", "2",
                             "--rigid-max-updates", "1", "--nicp-max-steps", "1", "--no-factor-reuse"], capsys)
    assert code == 0, err
    assert "Not the official protocol" in stdout
    settings = json.loads((out / "REALY_result.json").read_text())["settings"]
    assert settings["rigid_max_updates"] == 1 and settings["nicp_max_steps"] == 1 and not settings["factor_reuse"]


def test_cli_solver_choice_is_written_and_cholmod_without_cvxopt_is_exit_2(data, tmp_path, capsys, monkeypatch):
    out = tmp_path / "superlu"
    code, stdout, err = run(["realy", data.pred_dir, "--realy-root", data.realy_root, "-o", out,
                             "--solver", "superlu"], capsys)
    assert code == 0, err
    assert "Not the official protocol" not in stdout  # another solver keeps the official numbers
    result = json.loads((out / "REALY_result.json").read_text())
    assert result["settings"]["solver"] == "superlu"
    assert {d["solver"] for subject in result["details"].values() for d in subject.values()} == {"superlu"}
    from facegeo.eval import realy_solver

    monkeypatch.setattr(realy_solver, "cholmod_available", lambda: False)
    code, _, err = run(["realy", data.pred_dir, "--realy-root", data.realy_root, "-o", tmp_path / "x",
                        "--solver", "cholmod"], capsys)
    assert code == 2 and "facegeo[cholmod]" in err and len(err.strip().splitlines()) == 1
