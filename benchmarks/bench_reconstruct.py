"""End-to-end benchmark: ``facegeo reconstruct`` on the bundled photo, wall time and stages.

    python benchmarks/bench_reconstruct.py

Runs the command in a fresh process (as a user would: imports and model loading included) for
the default 1K maps and for ``--upscale 4`` (4K maps), and prints the wall time, the per-stage
breakdown from fit.json, and each configuration's ratio to the 1K run measured in the same run.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PHOTO = Path(__file__).resolve().parents[1] / "assets" / "photos" / "astronaut.png"
CONFIGS = {
    "1K, usdz + glb (default)": [],
    "1K, subdiv 2, usdz + glb": ["--subdiv", "2"],
    "4K (--upscale 4), usdz + glb": ["--upscale", "4"],
}


def run(extra: list[str]) -> tuple[float, dict]:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "facegeo.cli", "reconstruct", str(PHOTO), "-o", str(out), *extra],
                       check=True, capture_output=True)
        wall = time.perf_counter() - t0
        return wall, json.loads((out / "fit.json").read_text())["timings_s"]["stages"]


def main() -> None:
    rows = {name: run(extra) for name, extra in CONFIGS.items()}
    reference = rows[next(iter(CONFIGS))][0]
    stages = [k for k in next(iter(rows.values()))[1] if k != "total"]
    print("| configuration | wall s | ratio to 1K | " + " | ".join(stages) + " |")
    print("|---|---|---|" + "---|" * len(stages))
    for name, (wall, timings) in rows.items():
        cells = " | ".join(f"{timings.get(s, 0.0):.2f}" for s in stages)
        print(f"| {name} | {wall:.2f} | {wall / reference:.2f} | {cells} |")


if __name__ == "__main__":
    main()
