"""The command floor (facegeo.commands): one fitting group for every command that fits, choices
from the library's registries, help for every subcommand, a parser that imports nothing heavy."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from facegeo.assets import asset_path
from facegeo.commands import COMMAND_MODULES, COMMAND_OWNERS, build_parser, main
from facegeo.jobs import FitOptions, JobRecord

PHOTO = str(asset_path("photos/astronaut.png"))
FITTING = ("fit", "reconstruct", "unwrap")


def _subparsers():
    parser = build_parser()
    (sub,) = [a for a in parser._actions if a.dest == "command"]
    return sub.choices


def test_every_command_that_fits_takes_the_same_fitting_options():
    subparsers = _subparsers()
    groups = []
    for name in FITTING:
        actions = {a.dest: a for a in subparsers[name]._actions}
        group = {dest: (tuple(actions[dest].option_strings), actions[dest].default, tuple(actions[dest].choices or ()))
                 for dest in ("model", "landmarks", "focal", "max_side")}
        groups.append(group)
        args = subparsers[name].parse_args([PHOTO, "-o", "out", "--focal", "812.5", "--landmarks", "mediapipe", "--max-side", "640"])
        assert (args.focal, args.landmarks, args.max_side) == (812.5, "mediapipe", 640)
    assert groups[0] == groups[1] == groups[2]
    defaults = FitOptions()
    assert groups[0]["landmarks"][1] == defaults.landmarks and groups[0]["max_side"][1] == defaults.max_side


def test_choices_are_the_registries():
    from facegeo.asset import PART_CHOICES
    from facegeo.landmarks import DETECTORS
    from facegeo.texturing.registry import BACKENDS

    rec = {a.dest: a for a in _subparsers()["reconstruct"]._actions}
    assert list(rec["landmarks"].choices) == list(DETECTORS) and list(rec["backend"].choices) == list(BACKENDS)
    assert tuple(rec["parts"].choices) == PART_CHOICES
    train = {a.dest: a for a in _subparsers()["train-regressor"]._actions}
    assert list(train["landmarks"].choices) == ["auto", "truth", *DETECTORS]


def test_an_unknown_detector_is_one_usage_line(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["fit", PHOTO, "-o", "out", "--landmarks", "openpose"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and len(err.strip().splitlines()) == 1
    assert "openpose" in err and all(name in err for name in ("hybrid", "dlib", "mediapipe"))


def test_reconstruct_passes_focal_to_the_job(tmp_path, monkeypatch, capsys):
    seen = {}

    def job(photo, output, options, progress=None, fork=False):
        seen["options"] = options
        return JobRecord(str(photo), str(output), 1.0, 2.0, {"total": 0.0}, [], maps=["albedo"], map_size=64)

    monkeypatch.setattr("facegeo.jobs.reconstruct_into_folder", job)
    code = main(["reconstruct", PHOTO, "-o", str(tmp_path / "out"), "--focal", "900", "--landmarks", "dlib", "--maps", "albedo"])
    assert code == 0, capsys.readouterr().err
    options = seen["options"]
    assert (options.focal, options.landmarks, options.maps) == (900.0, "dlib", ("albedo",))


@pytest.mark.parametrize("name", [None, *("fit", "reconstruct", "unwrap", "export", "animate", "realy", "train-regressor",
                                          "make-synthetic-faces", "train-lora", "make-texture-pairs")])
def test_help_of_every_subcommand(name, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([name, "--help"] if name else ["--help"])
    out = capsys.readouterr().out
    assert exit_.value.code == 0 and out.startswith(f"usage: facegeo{' ' + name if name else ''}")


def test_the_subcommands_are_those_of_the_command_modules():
    from importlib import import_module

    declared = [c.name for m in COMMAND_MODULES for c in import_module(f"facegeo.commands.{m}").COMMANDS]
    assert list(_subparsers()) == declared and len(declared) == 11


def test_a_commands_own_parser_is_the_whole_parsers_part():
    """Each subcommand's owner is the module declaring it; the parser built for it alone has the
    same help and parses its command lines as the whole parser does."""
    from importlib import import_module

    assert COMMAND_OWNERS == {c.name: m for m in COMMAND_MODULES for c in import_module(f"facegeo.commands.{m}").COMMANDS}
    whole = _subparsers()
    for name in COMMAND_OWNERS:
        parser = build_parser(name)
        (sub,) = [a for a in parser._actions if a.dest == "command"]
        assert list(sub.choices) == [name]
        assert sub.choices[name].format_help() == whole[name].format_help()
    line = ["fit", PHOTO, "-o", "out", "--focal", "800", "--landmarks", "dlib"]
    assert vars(build_parser("fit").parse_args(line)) == vars(build_parser().parse_args(line))


def test_building_the_parser_imports_nothing_heavy():
    """Building the parser loads no heavy module (nor REALY's alignment: the realy command's defaults
    come from ``facegeo.eval.realy_settings``); a subcommand's help (which lists the detectors'
    registry) loads OpenCV with the detectors, but not torch."""
    code = ("import sys; from facegeo.commands import build_parser; parser = build_parser(); "
            "print(sorted(m for m in ('torch', 'cv2', 'diffusers', 'transformers', 'pxr', 'facegeo.eval.realy_align') "
            "if m in sys.modules)); "
            "(sub,) = [a for a in parser._actions if a.dest == 'command']; "
            "assert 'mediapipe' in sub.choices['reconstruct'].format_help(); "
            "print(sorted(m for m in ('torch', 'diffusers', 'transformers', 'pxr') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["[]", "[]"]


#: Modules whose import costs a user's wait (torch alone about two seconds on 2 cores) and which
#: ``facegeo fit`` does not use: the fit is NumPy, OpenCV, MediaPipe's LiteRT and dlib.
HEAVY_FOR_A_FIT = ("torch", "open3d", "pxr", "diffusers", "transformers", "dask", "sympy", "matplotlib", "scipy", "scipy.spatial",
                   "trimesh", "pymeshlab", "pygltflib")


def test_the_package_and_fit_help_import_nothing_heavy():
    code = ("import sys, runpy, facegeo; first = [m for m in HEAVY + ('cv2',) if m in sys.modules]; "
            "sys.argv = ['facegeo', 'fit', '--help']\n"
            "try:\n    runpy.run_module('facegeo.cli', run_name='__main__')\nexcept SystemExit:\n    pass\n"
            "print(first, [m for m in HEAVY if m in sys.modules], file=sys.stderr)")
    done = subprocess.run([sys.executable, "-c", f"HEAVY = {HEAVY_FOR_A_FIT!r}\n{code}"], capture_output=True, text=True, check=True)
    assert "usage: facegeo fit" in done.stdout
    assert done.stderr.strip() == "[] []"


def test_a_fit_imports_nothing_heavy(tmp_path):
    """The whole ``facegeo fit`` job on the bundled photo, in a fresh process."""
    code = (f"import sys; from facegeo.jobs import fit_into_folder; fit_into_folder({PHOTO!r}, {str(tmp_path / 'out')!r}); "
            f"print([m for m in {HEAVY_FOR_A_FIT!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    assert (tmp_path / "out" / "fit.json").is_file()


#: What ``facegeo reconstruct`` does not use: the texture stages, the parts and the preview are
#: NumPy and OpenCV (the preview's GGX shader too: facegeo.texturing.ggx); the export needs pxr
#: and pygltflib, the layout priors scipy.spatial (a fit alone needs no scipy at all).
HEAVY_FOR_A_RECONSTRUCTION = tuple(m for m in HEAVY_FOR_A_FIT if m not in ("pxr", "pygltflib", "scipy", "scipy.spatial"))


def test_a_reconstruction_imports_no_torch(tmp_path):
    """The whole ``facegeo reconstruct`` job (forked fit, preview) on the bundled photo at 256
    texels, in a fresh process."""
    code = (f"import sys; from facegeo.jobs import ReconstructOptions, reconstruct_into_folder; "
            f"reconstruct_into_folder({PHOTO!r}, {str(tmp_path / 'out')!r}, ReconstructOptions(size=256), fork=True); "
            f"print([m for m in {HEAVY_FOR_A_RECONSTRUCTION!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    assert {"preview.png", "face.usdz", "face.glb"} <= {p.name for p in (tmp_path / "out").iterdir()}
    # one run, one record: asset.json's stage timings are fit.json's (the forked fit's own seconds,
    # not the parent's hand-over), and so are the fit's own timings
    fit_record = json.loads((tmp_path / "out" / "fit.json").read_text())
    metadata = json.loads((tmp_path / "out" / "asset.json").read_text())["metadata"]
    stages = fit_record["timings_s"].pop("stages")
    assert metadata["timings_s"] == {name: stages[name] for name in metadata["timings_s"]}
    assert set(metadata["timings_s"]) == {"fit", "unwrap", "inpaint", "homogenise", "materials", "upscale", "parts"}
    assert stages["fit"] >= sum(fit_record["timings_s"][name] for name in ("detect", "landmarks")) > 0.01
    assert metadata["fit"]["timings_s"] == fit_record["timings_s"]


RUN = """
import sys, threading, time, pathlib
import facegeo.cli as cli
flag = pathlib.Path(sys.argv[2])
def main():
    if sys.argv[1] == "thread":  # a non-daemon thread still working: the process must wait for it
        threading.Thread(target=lambda: (time.sleep(0.3), flag.write_text("done"))).start()
    print("unflushed", end="")
    return 3
cli.main = main
cli.run()
"""


@pytest.mark.parametrize("case", ["plain", "thread"])
def test_the_console_entry_flushes_keeps_the_status_and_waits_for_working_threads(tmp_path, case):
    flag = tmp_path / "flag"
    done = subprocess.run([sys.executable, "-c", RUN, case, str(flag)], capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stdout) == (3, "unflushed")
    assert flag.exists() == (case == "thread")
