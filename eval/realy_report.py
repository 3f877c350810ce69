"""Output files of a REALY evaluation: the official REALY_error.txt, Markdown, CSV and JSON.

``write_outputs(result, out_dir)`` writes, atomically (a failed run leaves nothing):

* ``REALY_error.txt``: one line per prediction in the official format (name, an empty field,
  then nose, mouth, forehead, cheek in mm, each ``str(value)[:9]``, tab-separated);
* ``REALY_summary.md``: mean ± std (n - 1) per region and All, then the median, the knobs when
  they are not the official protocol's, and the values whose numerical uncertainty exceeds
  ``UNCERTAINTY_FLAG`` (1e-6 relative);
* ``REALY_summary.csv``: one row per prediction (full precision), then mean, median and std rows;
* ``REALY_result.json``: per-subject values, the 9-character texts, the summary, the numerical
  uncertainty of every value (relative), the settings, timings and solver details.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
from pathlib import Path

from facegeo.eval.realy import REGIONS, UNCERTAINTY_FLAG, RealyResult
from facegeo.staged_output import StagedOutput

__all__ = ["markdown_table", "csv_text", "json_text", "write_outputs", "OUTPUT_FILES"]

OUTPUT_FILES = ("REALY_error.txt", "REALY_summary.md", "REALY_summary.csv", "REALY_result.json")

_TITLES = {"nose": "Nose", "mouth": "Mouth", "forehead": "Forehead", "cheek": "Cheek"}


def _fmt(x: float, digits: int = 3) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def markdown_table(result: RealyResult) -> str:
    """A Markdown table: mean ± std and median per region (mm), and All."""
    s = result.summary
    head = "| | " + " | ".join(_TITLES[r] for r in REGIONS) + " | All |"
    rule = "|---|" + "---:|" * (len(REGIONS) + 1)
    mean = "| mean ± std (mm) | " + " | ".join(
        f"{_fmt(s[r]['mean'])} ± {_fmt(s[r]['std'])}" for r in REGIONS) + f" | {_fmt(s['all'])} |"
    median = "| median (mm) | " + " | ".join(_fmt(s[r]["median"]) for r in REGIONS) + " | |"
    note = (f"\nREALY, {s['n']} prediction(s), topology {result.topology}; std with n - 1; "
            "All = mean of the four region means.\n")
    loosened = result.settings.loosened()
    if loosened:
        changed = ", ".join(f"{name}={value}" for name, value in loosened.items())
        note += f"\n**Not the official protocol**: {changed} (the numbers differ from the official ones).\n"
    if not result.settings.follow_decisions:
        note += ("\nThe uncertainties count the final closest points' ties only (--no-follow-decisions): "
                 "they are lower bounds.\n")
    flagged = result.uncertain(UNCERTAINTY_FLAG)
    if flagged:
        note += (f"\nNumerically uncertain (round-off can move the value by more than {UNCERTAINTY_FLAG:g} "
                 "relative, through decisions of the protocol it can turn; the official code's number can "
                 "differ by up to the uncertainty given): "
                 + ", ".join(f"{name} {region} ({u:.1e})" for name, region, u in flagged) + ".\n")
    return "\n".join([head, rule, mean, median]) + "\n" + note


def csv_text(result: RealyResult) -> str:
    """Per-prediction rows (full precision, mm), then mean, median and std rows."""
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["subject", *REGIONS])
    for name, values in result.per_subject.items():
        w.writerow([name, *(repr(values[r]) for r in REGIONS)])
    for stat in ("mean", "median", "std"):
        w.writerow([stat, *(repr(result.summary[r][stat]) for r in REGIONS)])
    w.writerow(["all", repr(result.summary["all"]), "", "", ""])
    return out.getvalue()


def json_text(result: RealyResult) -> str:
    def clean(x):
        if isinstance(x, float) and not math.isfinite(x):
            return None
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        return x

    data = {
        "protocol": "REALY (ECCV 2022), official main.py semantics",
        "topology": result.topology,
        "regions": list(REGIONS),
        "per_subject_mm": result.per_subject,
        "per_subject_text": result.text,
        "summary": clean(result.summary),
        "uncertainty_relative": result.uncertainty,
        "uncertainty_flag": UNCERTAINTY_FLAG,
        "settings": dataclasses.asdict(result.settings),
        "workers": result.workers,
        "wall_seconds": result.wall_seconds,
        "seconds": result.seconds,
        "details": result.details,
    }
    return json.dumps(data, indent=1)


def write_outputs(result: RealyResult, out_dir: str | Path) -> list[Path]:
    """Write the four files into ``out_dir`` (created; staged, so all or nothing)."""
    with StagedOutput(out_dir) as stage:
        stage.path("REALY_error.txt").write_text(result.error_txt())
        stage.path("REALY_summary.md").write_text(markdown_table(result))
        stage.path("REALY_summary.csv").write_text(csv_text(result))
        stage.path("REALY_result.json").write_text(json_text(result))
    return [Path(out_dir) / name for name in OUTPUT_FILES]
