"""``facegeo realy PRED_DIR``: the REALY benchmark (:func:`facegeo.eval.realy.evaluate`) on a
folder of predicted meshes, written as REALY's files and facegeo's summaries."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from pathlib import Path

from facegeo.commands.arguments import Command

__all__ = ["COMMANDS"]


def _arguments(p: argparse.ArgumentParser) -> None:
    from facegeo.eval.realy_settings import EXACT, SOLVERS

    p.add_argument("pred_dir", type=Path, metavar="PRED_DIR", help="folder of predicted meshes (.obj)")
    p.add_argument("--realy-root", type=Path, default=None,
                   help="folder holding REALY's data/ (REALY_HIFI3D_keypoints/, REALY_scan_region/, "
                   "metrical_scale.txt, <TOPOLOGY>.obj/.txt)")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--topology", default=None, metavar="NAME",
                       help="prediction topology: data/NAME.obj + data/NAME.txt (e.g. HIFI3D, BFM09, FLAME); "
                       "default ICT-FaceKit (facegeo's model, keypoints bundled)")
    which.add_argument("--keypoints", type=Path, default=None, metavar="FILE",
                       help="REALY barycentric keypoint file (85 rows [triangle, w0, w1]) of the prediction "
                       "topology; its triangles come from --template or FILE's .obj sibling, else each prediction")
    p.add_argument("--template", type=Path, default=None, metavar="OBJ", help="template mesh of --keypoints")
    p.add_argument("--template-mask", type=Path, default=None, metavar="FILE",
                   help="official --template_mask: comma-separated 0/1 per vertex; only triangles whose "
                   "vertices are all 1 are used in the error step")
    p.add_argument("--keypoints-dir", type=Path, default=None, metavar="DIR",
                   help="override data/REALY_HIFI3D_keypoints")
    p.add_argument("--regions-dir", type=Path, default=None, metavar="DIR", help="override data/REALY_scan_region")
    p.add_argument("--scale-path", type=Path, default=None, metavar="FILE", help="override data/metrical_scale.txt")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="processes; the regions of all subjects are shared among them (the numbers do not change)")
    p.add_argument("--scheduler", default=os.environ.get("DASK_SCHEDULER_ADDRESS") or None, metavar="ADDRESS",
                   help="share the regions among the workers of the Dask cluster at ADDRESS instead "
                   "(default $DASK_SCHEDULER_ADDRESS; needs facegeo[batch] here and on the workers; the numbers do not change)")
    p.add_argument("--solver", choices=SOLVERS, default=EXACT.solver,
                   help="linear solver of the non-rigid ICP: CHOLMOD at every step (needs facegeo[cholmod]) or "
                   "SciPy's SuperLU with its factor reused in each stage; both give the official numbers "
                   "(default auto: CHOLMOD when installed)")
    knobs = p.add_argument_group(
        "speed against exactness", "Loosen the official protocol for speed (the defaults are exact; "
        "benchmarks/RESULTS.md has the error against time of each)")
    knobs.add_argument("--rigid-tol", type=float, default=EXACT.rigid_tolerance, metavar="T",
                       help="rigid ICP stops when its mean squared residual changes by less (default %(default)g)")
    knobs.add_argument("--rigid-max-updates", type=int, default=EXACT.rigid_max_updates, metavar="N",
                       help="at most N rigid ICP updates per region (default %(default)d)")
    knobs.add_argument("--nicp-epsilon-scale", type=float, default=EXACT.nicp_epsilon_scale, metavar="S",
                       help="multiply the non-rigid ICP's stopping thresholds (default %(default)g)")
    knobs.add_argument("--nicp-max-steps", type=int, default=None, metavar="N",
                       help="at most N solves per stiffness stage (default: official, 11 with keypoints, no limit for the cheek)")
    knobs.add_argument("--solver-rtol", type=float, default=EXACT.solver_rtol, metavar="R",
                       help="superlu solver: relative residual of its factor-preconditioned CG solves (default %(default)g)")
    knobs.add_argument("--no-factor-reuse", action="store_true",
                       help="superlu solver: factor every linear system (slower, the same numbers to rounding)")
    knobs.add_argument("--no-follow-decisions", action="store_true",
                       help="do not follow the non-rigid ICP's decisions that round-off could turn (a third less time; "
                       "the same numbers, but their reported uncertainty then counts the final ties only: a lower bound)")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="OUT",
                   help="output folder (default: PRED_DIR/realy_eval)")


def _run(args: argparse.Namespace) -> None:
    from facegeo.errors import FacegeoError, InputError
    from facegeo.eval.realy import DEFAULT_TOPOLOGY, evaluate
    from facegeo.eval.realy_settings import Settings
    from facegeo.eval.realy_solver import resolve as resolve_solver
    from facegeo.eval.realy_report import OUTPUT_FILES, markdown_table, write_outputs

    if args.workers < 1:
        raise InputError("--workers", "value", "a positive number of processes", str(args.workers))
    if args.scheduler and args.workers != 1:
        raise InputError("--workers", "value", "no --workers with --scheduler (the cluster has its workers)", str(args.workers))
    if args.template is not None and args.keypoints is None:
        raise InputError(args.template, "--template", "to be used with --keypoints FILE")
    try:
        settings = Settings(rigid_tolerance=args.rigid_tol, rigid_max_updates=args.rigid_max_updates,
                            nicp_epsilon_scale=args.nicp_epsilon_scale, nicp_max_steps=args.nicp_max_steps,
                            solver_rtol=args.solver_rtol, factor_reuse=not args.no_factor_reuse, solver=args.solver,
                            follow_decisions=not args.no_follow_decisions)
    except ValueError as exc:
        raise InputError("<arguments>", "speed / exactness options", "positive values", str(exc)) from None
    try:
        resolve_solver(args.solver)
    except FacegeoError as exc:  # cholmod without CVXOPT
        raise InputError("--solver", "value", f"auto or superlu ({exc})", args.solver) from None
    start = time.perf_counter()
    with contextlib.ExitStack() as stack:
        client = None
        if args.scheduler:
            from facegeo.batch import dask_client

            client = stack.enter_context(dask_client(scheduler=args.scheduler))
        result = evaluate(
            args.pred_dir,
            args.realy_root,
            topology=args.topology or DEFAULT_TOPOLOGY,
            keypoints=args.keypoints,
            workers=args.workers,
            template=args.template,
            keypoints_dir=args.keypoints_dir,
            regions_dir=args.regions_dir,
            scale_path=args.scale_path,
            template_mask=args.template_mask,
            settings=settings,
            progress=None if sys.stderr.isatty() else False,
            client=client,
        )
    out = args.output if args.output is not None else args.pred_dir / "realy_eval"
    write_outputs(result, out)
    print(markdown_table(result), end="")
    print(f"evaluated {result.summary['n']} prediction(s) in {time.perf_counter() - start:.1f} s; "
          f"wrote {out}/{{{','.join(OUTPUT_FILES)}}}")


COMMANDS = (
    Command(
        "realy",
        help="REALY benchmark: region-wise error (mm) of predicted meshes against the REALY scans",
        description="Evaluate every PRED_DIR/<id>.obj (frontal track) or <id>_<view>.obj (multi-view "
        "track) with the REALY protocol (ECCV 2022), numbers equal to the official code. Writes "
        "REALY_error.txt (official format), REALY_summary.md, REALY_summary.csv and REALY_result.json.",
        arguments=_arguments,
        run=_run,
    ),
)
