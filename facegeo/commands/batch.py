"""The batch run of ``fit`` and ``reconstruct`` (several photos, a folder, a glob or a manifest;
the options are :func:`facegeo.commands.arguments.add_batch_arguments`, the engine
:mod:`facegeo.batch`): prints the outcome and returns the exit status
(:data:`facegeo.batch.EXIT_STATUS`)."""

from __future__ import annotations

import argparse
import sys
import time
from typing import TYPE_CHECKING

from facegeo.batch import FAILURES_FILE, ITEMS_FILE, SUMMARY_FILE, BatchRecord, fit_many, reconstruct_many
from facegeo.commands.arguments import COMMAND_LINE
from facegeo.errors import InputError

if TYPE_CHECKING:
    from facegeo.jobs import FitOptions

__all__ = ["run_batch"]


def run_batch(args: argparse.Namespace, kind: str, options: FitOptions) -> int:
    """Run the batch ``args`` ask for (``kind``: "fit" or "reconstruct") and print its outcome;
    returns the exit status (:data:`EXIT_STATUS`). Failed photos are listed on stderr as they fail."""
    import signal

    many = fit_many if kind == "fit" else reconstruct_many
    if args.retries < 0:
        raise InputError(COMMAND_LINE, "--retries", "a number ≥ 0", str(args.retries))

    def report(record: BatchRecord) -> None:
        from tqdm import tqdm

        where = "" if record.error.startswith(record.photo) else f"{record.photo}: "
        tqdm.write(f"facegeo: failed: {where}{record.error}", file=sys.stderr)

    start = time.perf_counter()
    try:
        records = many(args.photo, args.output, None, options, workers=args.workers, scheduler=args.scheduler,
                       resume=args.resume, retries=args.retries, allowed_failures=args.retries,
                       files="client" if args.send_files else "shared", progress=None, on_failure=report)
    except KeyboardInterrupt as exc:
        signum = int(getattr(exc, "signum", signal.SIGINT))
        print(f"facegeo: interrupted ({signal.Signals(signum).name}); complete item folders kept in {args.output}, "
              f"finish with --resume", file=sys.stderr)
        return 128 + signum
    counts = {s: sum(r.status == s for r in records) for s in ("done", "skipped", "failed")}
    print(f"{kind} {len(records)} photo(s) in {time.perf_counter() - start:.1f} s: {counts['done']} done, "
          f"{counts['skipped']} skipped (complete before), {counts['failed']} failed"
          + (f" (see {args.output}/{FAILURES_FILE})" if counts["failed"] else ""))
    print(f"wrote {args.output}/{{<photo>/,{ITEMS_FILE},{SUMMARY_FILE},{FAILURES_FILE}}}")
    return 3 if counts["failed"] else 0
