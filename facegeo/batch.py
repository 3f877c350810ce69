"""Many photos at once, on one machine or on a Dask cluster: ``facegeo fit`` / ``facegeo
reconstruct`` with several inputs, and :func:`fit_many` / :func:`reconstruct_many` from Python.

Every item runs the one-photo job of :mod:`facegeo.jobs` (:func:`~facegeo.jobs.fit_into_folder`,
:func:`~facegeo.jobs.reconstruct_into_folder`) into its own folder ``OUT/<name>``, written
through :class:`~facegeo.staged_output.StagedOutput`: an item folder is complete or absent.

Inputs (:func:`expand_inputs`): photo paths, folders (their image files, not recursive), glob
patterns (``**`` recurses) and manifest files (``.txt`` / ``.lst``: one path per line, relative
to the manifest's folder; blank lines and ``#`` comments skipped). A photo named twice counts once.

Output folder ``OUT`` (see :data:`ITEMS_FILE`, :data:`SUMMARY_FILE`, :data:`FAILURES_FILE`):

* ``OUT/<name>/``: one folder per photo, named after the photo's stem; a name already taken (two
  ``face.jpg`` from two folders, ``a.png`` and ``a.jpg``, a case-only difference) gets ``-2``,
  ``-3``, ... and the renaming is recorded in ``items.csv`` (``photo, folder, note``), written
  before any work; ``--resume`` reuses it, so a photo always goes to the same folder;
* ``summary.csv``: one row per photo: status (``done``, ``skipped`` = complete from an earlier
  run, ``failed``), landmark RMS in px and in % of the inter-ocular distance, seconds per stage,
  the worker's peak resident memory during the item (MiB), tries, the error of a failed item;
* ``failures.csv``: the failed photos with their one-line error (header only when none failed).

An existing ``OUT`` must be empty, or an earlier batch output (it holds ``items.csv``) and
``--resume`` given: then the photos whose folder is complete are skipped and the others (failed,
interrupted, new) are processed. Without ``--resume`` an earlier batch output is refused rather
than replaced (it may hold days of work). One batch at a time per ``OUT``: the batch holds
``OUT``'s lock (:func:`facegeo.staged_output.locked_output`) and each item job its folder's, so a
second batch into ``OUT``, or any run into one of its item folders, is refused at once with the
other run's process id.

Engine: an embedded :class:`distributed.LocalCluster` (``workers`` processes, one thread each;
the model and the landmark detectors are loaded once per worker process), an existing cluster
(``scheduler`` address, default ``$DASK_SCHEDULER_ADDRESS``) or, from Python, an existing
:class:`distributed.Client`. Outputs: the workers write into ``OUT`` directly, so ``OUT`` must
be on a file system they share with the client (``files="shared"``, the default); or, with
``files="client"``, each worker writes into its own temporary folder and sends the files back,
and the client writes them into ``OUT`` (no shared file system needed; the files travel through
the scheduler's network). An object store is not supported. The records always come back to
the client.

Faults: a photo that fails with a :class:`~facegeo.errors.FacegeoError` (unreadable, no face,
failed fit checks) is failed at once; any other exception is retried ``retries`` times (Dask's
``retries=``); a worker that dies while running an item (a crash, or the nanny killing it for its
memory limit) gets the item re-run on another worker, and an item that has killed
``allowed_failures`` + 1 workers is failed (Dask's ``distributed.scheduler.allowed-failures``, set
on the embedded cluster's scheduler; an external scheduler uses its own setting); should the
embedded cluster be left without any worker for a minute, the photos still waiting fail. Ctrl-C
(SIGINT) or SIGTERM cancels the batch: finished item folders stay, unfinished ones never appear,
``summary.csv`` lists what finished, and ``--resume`` goes on from there.

Exit status of the command (:data:`EXIT_STATUS`): 0 every photo done or skipped; 3 the batch ran
to its end but some photos failed (see failures.csv); 2 bad invocation (no inputs, an unusable
``OUT``, an unreachable scheduler); 130 / 143 interrupted (SIGINT / SIGTERM).
"""

from __future__ import annotations

import contextlib
import csv
import glob
import io
import logging
import os
import shutil
import signal
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from facegeo.errors import FacegeoError, InputError

if TYPE_CHECKING:  # facegeo.jobs imports torch (its option defaults check the detectors): not for the CLI parser
    from facegeo.jobs import FitOptions, JobRecord, ReconstructOptions

__all__ = ["BatchRecord", "fit_many", "reconstruct_many", "expand_inputs", "folder_names", "dask_client",
           "EXIT_STATUS", "SCHEDULER_ENV", "GLOB_CHARS", "ITEMS_FILE", "SUMMARY_FILE",
           "FAILURES_FILE", "MANIFEST_SUFFIXES"]

ITEMS_FILE = "items.csv"
SUMMARY_FILE = "summary.csv"
FAILURES_FILE = "failures.csv"
#: Files with these suffixes are manifests (one photo path per line), not photos.
MANIFEST_SUFFIXES = (".txt", ".lst")
#: Exit status of a batch command.
EXIT_STATUS = {0: "every photo done or skipped", 3: "the batch ran to its end but some photos failed (failures.csv)",
               2: "bad invocation: no inputs, an unusable OUT, an unreachable scheduler",
               130: "interrupted by SIGINT (Ctrl-C)", 143: "interrupted by SIGTERM"}
_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".dib", ".gif", ".webp", ".ppm", ".pgm", ".pnm", ".avif"}
GLOB_CHARS = set("*?[")
_RESERVED = {ITEMS_FILE, SUMMARY_FILE, FAILURES_FILE}
_MAX_NAME_BYTES = 200  # leaves room for "-N" and the staging suffix under NAME_MAX (255)
_FLUSH_SECONDS = 30.0  # summary.csv is rewritten at most this often while a batch runs
_JOBS = {"fit": "fit_into_folder", "reconstruct": "reconstruct_into_folder"}
_COMMAND_LINE = "<command line>"
SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"


@dataclass
class BatchRecord:
    """What became of one input photo.

    Attributes:
        photo: the photo's absolute path. output: its item folder (absolute).
        status: ``done`` (processed now), ``skipped`` (complete from an earlier run) or ``failed``.
        error: the one-line error of a failed photo ("" otherwise).
        landmark_rms_px, landmark_rms_percent_iod: the fit's landmark RMS (px, % of the
            inter-ocular distance); None unless done.
        timings: seconds per stage (the job's ``timings``); peak_memory_mib: the worker's peak
            resident memory while it ran this item (MiB; None when unknown).
        worker: the Dask worker that ran it; tries: 1, or for a photo failed because its job ended
            its worker each time, the number of workers it ended (allowed failures + 1).
        note: how the folder was named when its stem was taken. job: the job's own record.
    """

    photo: str
    output: str
    status: str
    error: str = ""
    landmark_rms_px: float | None = None
    landmark_rms_percent_iod: float | None = None
    timings: dict[str, float] = field(default_factory=dict)
    peak_memory_mib: float | None = None
    worker: str = ""
    tries: int = 0
    note: str = ""
    job: JobRecord | None = None


# -------------------------------------------------------------------------------------- inputs
def expand_inputs(specs: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """The photos named by ``specs``, absolute, in order, each once: a folder gives its image files
    (sorted, not recursive), a glob pattern its matches (sorted; ``**`` recurses), a manifest
    (:data:`MANIFEST_SUFFIXES`) the paths on its lines, any other path itself (a missing or bad
    photo fails as an item, so that one bad line does not stop 70,000 others).

    Raises:
        InputError: an unreadable manifest, a pattern or folder that matches no image, no inputs.
    """
    photos: list[Path] = []
    for spec in specs:
        text = os.fspath(spec)
        path = Path(text)
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix.lower() in _IMAGE_SUFFIXES and p.is_file())
            if not found:
                raise InputError(text, "input folder", "a folder holding image files (PNG, JPEG, ...)", "none")
            photos += found
        elif path.suffix.lower() in MANIFEST_SUFFIXES and path.is_file():
            photos += _read_manifest(path)
        elif not path.exists() and GLOB_CHARS & set(text):
            found = sorted(Path(p) for p in glob.glob(os.path.expanduser(text), recursive=True) if Path(p).is_file())
            if not found:
                raise InputError(text, "glob pattern", "a pattern that matches files", "no match")
            photos += found
        else:
            photos.append(path)
    unique = list(dict.fromkeys(Path(os.path.abspath(p)) for p in photos))
    if not unique:
        raise InputError(_COMMAND_LINE, "photos", "one or more photos, folders, glob patterns or manifests", "none")
    return unique


def _read_manifest(path: Path) -> list[Path]:
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, "manifest", "a readable UTF-8 text file, one photo path per line", type(exc).__name__) from None
    entries = [line.strip() for line in lines]
    return [p if p.is_absolute() else path.parent / p
            for p in (Path(os.path.expanduser(e)) for e in entries if e and not e.startswith("#"))]


def _stem_name(photo: Path) -> str:
    name = photo.stem.strip() or "photo"
    if name.startswith(".") or name.casefold() in _RESERVED:
        name = "_" + name
    encoded = name.encode("utf-8")
    if len(encoded) > _MAX_NAME_BYTES:
        name = encoded[:_MAX_NAME_BYTES].decode("utf-8", errors="ignore")
    return name


def folder_names(photos: Sequence[Path], known: dict[str, str] | None = None) -> list[tuple[str, str]]:
    """``(folder name, note)`` for each photo: ``known`` (photo path -> name, from an earlier
    ``items.csv``) first, then the photo's stem, or ``stem-2``, ``stem-3``, ... when that name
    is taken (compared case-insensitively, for case-insensitive file systems); ``note`` says so."""
    known = known or {}
    taken: dict[str, str] = {name.casefold(): photo for photo, name in known.items()}
    result: list[tuple[str, str]] = []
    for photo in photos:
        key = str(photo)
        if key in known:
            result.append((known[key], ""))
            continue
        base = _stem_name(photo)
        name, n = base, 1
        while name.casefold() in taken:
            n += 1
            name = f"{base}-{n}"
        note = f"renamed from {base}: taken by {taken[base.casefold()]}" if n > 1 else ""
        taken[name.casefold()] = key
        result.append((name, note))
    return result


# ------------------------------------------------------------------------------- worker side
def _reset_peak_memory() -> None:
    """Reset the process's peak resident set size (Linux: /proc/self/clear_refs, "5")."""
    with contextlib.suppress(OSError):
        Path("/proc/self/clear_refs").write_text("5")


def _peak_memory_mib() -> float | None:
    """Peak resident memory since the last reset (MiB): VmHWM on Linux; elsewhere None."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().name)
    except (ImportError, ValueError):
        return f"pid {os.getpid()}"


def _read_tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _run_item(job: Callable[..., JobRecord], photo: str, output: str, options: FitOptions,
              send_files: bool) -> dict[str, Any]:
    """One item on a worker: the job into ``output`` (or, with ``send_files``, into a local
    temporary folder whose files are returned). A :class:`FacegeoError` is the photo's failure
    (returned, not retried); any other exception propagates, for Dask to retry."""
    _reset_peak_memory()
    outcome: dict[str, Any] = {"worker": _worker_name()}
    scratch = Path(tempfile.mkdtemp(prefix="facegeo-batch-")) if send_files else None
    try:
        record = job(photo, output if scratch is None else scratch / "item", options)
        if scratch is not None:
            outcome["files"] = _read_tree(scratch / "item")
            record.output = output
        outcome["record"] = record
    except FacegeoError as exc:
        outcome["error"] = str(exc)
    finally:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
    outcome["peak_memory_mib"] = _peak_memory_mib()
    return outcome


# ------------------------------------------------------------------------------------ engine
@contextlib.contextmanager
def _quiet_dask() -> Iterator[None]:
    """Dask's own log lines (worker restarts, connection chatter) off stderr; errors stay."""
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def dask_setup(worker: Any) -> None:
    """Dask's preload hook, run in each worker process of the embedded cluster as it starts: the
    worker ignores SIGINT. A terminal's Ctrl-C reaches every process of its group; this process
    alone answers it (the batch cancelled, the reports written, the cluster closed), where each
    worker used to die on its own with a KeyboardInterrupt traceback and the nanny's errors."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _import_distributed() -> Any:
    try:
        import distributed
    except ImportError:
        raise InputError(_COMMAND_LINE, "batch engine", "Dask distributed installed (pip install 'facegeo[batch]')",
                         "no module named distributed") from None
    return distributed


@contextlib.contextmanager
def dask_client(client: Any = None, scheduler: str | None = None, workers: int | None = None,
                allowed_failures: int = 2, memory_limit: str | float | None = None) -> Iterator[Any]:
    """A :class:`distributed.Client` for a batch: ``client`` itself (left open), one connected to
    ``scheduler`` (an address such as ``tcp://host:8786``), or one on an embedded
    :class:`distributed.LocalCluster` of ``workers`` processes (default: the usable CPU cores),
    one thread each, no dashboard, ``allowed_failures`` worker deaths per task before it is
    failed, ``memory_limit`` per worker (Dask's default: the machine's memory shared equally).
    Closed (the embedded cluster shut down) on the way out.

    Raises:
        InputError: Dask not installed, ``workers`` < 1, or the scheduler not reachable.
    """
    if client is not None:
        yield client
        return
    distributed = _import_distributed()
    import dask

    with _quiet_dask():
        if scheduler:
            try:
                connected = distributed.Client(scheduler, timeout="20s")
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError(_COMMAND_LINE, "--scheduler", "the address of a reachable Dask scheduler",
                                 f"{scheduler} ({type(exc).__name__}: {exc})") from None
            try:
                yield connected
            finally:
                connected.close()
            return
        n = workers if workers is not None else len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        if n < 1:
            raise InputError(_COMMAND_LINE, "--workers", "a positive number of worker processes", str(n))
        # Dask starts its workers with MALLOC_TRIM_THRESHOLD_=65536 (glibc then hands freed memory
        # back at once and stops adapting its mmap threshold): an item's large arrays were mapped
        # and faulted in again and again, 2.2-2.9 s of system time a photo (benchmarks/RESULTS.md)
        environ = {key: value for key, value in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
                   if key != "MALLOC_TRIM_THRESHOLD_"}
        with dask.config.set({"distributed.scheduler.allowed-failures": int(allowed_failures),
                              "distributed.nanny.pre-spawn-environ": environ}):
            cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                                               scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},  # its HTTP routes on a free port
                                               silence_logs=logging.ERROR, memory_limit=memory_limit or "auto",
                                               preload=[__name__])  # dask_setup below, in each worker process
        try:
            local = distributed.Client(cluster)
            try:
                yield local
            finally:
                local.close()
        finally:
            cluster.close()


# --------------------------------------------------------------------------------- the batch
def _prepare_output(out: Path, resume: bool) -> dict[str, str]:
    """Check (and create) the batch folder; return the photo -> folder name map of an earlier
    batch in it (``items.csv``) when resuming."""
    from facegeo.output_lock import LOCK_PREFIX
    from facegeo.staged_output import TEMP_PREFIX, check_output_location, remove_stale_temporaries

    check_output_location(out, folder=True)
    if not out.exists():
        out.mkdir(parents=True)
        return {}
    remove_stale_temporaries(out)
    items = out / ITEMS_FILE
    if items.is_file():
        if not resume:
            raise InputError(out, "output folder", "a new or empty folder, or --resume to complete the earlier batch in it",
                             f"an earlier batch output ({ITEMS_FILE})")
        with items.open(newline="", encoding="utf-8") as fh:
            return {row["photo"]: row["folder"] for row in csv.DictReader(fh)}
    entries = sorted(e.name for e in out.iterdir() if not e.name.startswith((TEMP_PREFIX, LOCK_PREFIX)))
    if entries:
        raise InputError(out, "output folder", f"a new or empty folder, or an earlier batch output (with {ITEMS_FILE})",
                         f"a folder with other files ({', '.join(entries[:3])}{', ...' if len(entries) > 3 else ''})")
    return {}


def _csv_text(header: Sequence[str], rows: Iterable[dict[str, Any]]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(header), extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def _number(value: float | None, digits: int) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def _summary_row(record: BatchRecord) -> dict[str, str]:
    row = {"photo": record.photo, "folder": Path(record.output).name, "status": record.status,
           "landmark_rms_px": _number(record.landmark_rms_px, 4),
           "landmark_rms_percent_iod": _number(record.landmark_rms_percent_iod, 4),
           "peak_memory_mib": _number(record.peak_memory_mib, 1), "worker": record.worker,
           "tries": str(record.tries), "error": record.error, "note": record.note}
    row.update({f"seconds_{k}": f"{v:.3f}" for k, v in record.timings.items()})
    return row


_SUMMARY_HEAD = ["photo", "folder", "status", "landmark_rms_px", "landmark_rms_percent_iod"]
_SUMMARY_TAIL = ["peak_memory_mib", "worker", "tries", "error", "note"]


def _write_reports(out: Path, records: Sequence[BatchRecord], earlier: dict[str, dict[str, str]]) -> None:
    """summary.csv and failures.csv of ``records`` (a skipped photo keeps its earlier row)."""
    from facegeo.staged_output import atomic_write_text

    rows = []
    for record in records:
        row = _summary_row(record)
        if record.status == "skipped" and record.photo in earlier:
            row = {**earlier[record.photo], "status": "skipped"}
        rows.append(row)
    stages = list(dict.fromkeys(k for row in rows for k in row if k.startswith("seconds_")))
    atomic_write_text(out / SUMMARY_FILE, _csv_text(_SUMMARY_HEAD + stages + _SUMMARY_TAIL, rows))
    failed = [r for r in records if r.status == "failed"]
    atomic_write_text(out / FAILURES_FILE, _csv_text(["photo", "folder", "tries", "error"],
                                                     ({**_summary_row(r)} for r in failed)))


def _read_earlier_summary(out: Path) -> dict[str, dict[str, str]]:
    path = out / SUMMARY_FILE
    if not path.is_file():
        return {}
    with path.open(newline="", encoding="utf-8") as fh:
        return {row["photo"]: row for row in csv.DictReader(fh) if row.get("status") in ("done", "skipped")}


def _complete(folder: Path) -> bool:
    """An item folder is complete when it exists with its fit.json (a new item folder is renamed
    in as a whole, and a commit into an existing one that a killed worker left half done is rolled
    back by :func:`_prepare_output` before this is asked)."""
    return (folder / "fit.json").is_file()


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _run_many(kind: str, photos: Iterable[str | os.PathLike[str]], out: str | os.PathLike[str], client: Any,
              options: FitOptions, *, workers: int | None, scheduler: str | None, resume: bool, retries: int,
              allowed_failures: int, files: str, job: Callable[..., JobRecord] | None, memory_limit: str | float | None,
              progress: bool | None, on_failure: Callable[[BatchRecord], None] | None) -> list[BatchRecord]:
    from facegeo import jobs
    from facegeo.staged_output import (StagedOutput, atomic_write_text, check_output_location, locked_output,
                                       remove_other_temporaries, remove_stale_temporaries)

    if files not in ("shared", "client"):
        raise InputError("<options>", "files", "'shared' or 'client'", repr(files))
    if retries < 0 or allowed_failures < 0:
        raise InputError(_COMMAND_LINE, "--retries", "a number of retries ≥ 0", str(min(retries, allowed_failures)))
    if scheduler and workers is not None:
        raise InputError(_COMMAND_LINE, "--workers", "no --workers with --scheduler (the cluster has its workers)", str(workers))
    job = job or getattr(jobs, _JOBS[kind])
    paths = expand_inputs(photos)
    out = Path(os.path.abspath(out))
    if any(out == p or out in p.parents for p in paths):
        raise InputError(out, "output folder", "a folder that does not hold the input photos", "it holds some")
    check_output_location(out, folder=True)
    with locked_output(out):  # one batch at a time per OUT (items hold their own folder's lock)
        known = _prepare_output(out, resume)
        names = folder_names(paths, known)
        atomic_write_text(out / ITEMS_FILE, _csv_text(["photo", "folder", "note"], (
            {"photo": str(p), "folder": name, "note": note} for p, (name, note) in zip(paths, names))))
        earlier = _read_earlier_summary(out) if resume else {}
        records = [BatchRecord(photo=str(p), output=str(out / name), status="pending", note=note)
                   for p, (name, note) in zip(paths, names)]
        todo = []
        for i, record in enumerate(records):
            if resume and _complete(Path(record.output)):
                record.status = "skipped"
            else:
                todo.append(i)

        from tqdm import tqdm

        interrupted = True
        bar = tqdm(total=len(todo), desc=kind, unit="photo", disable=not sys.stderr.isatty() if progress is None else not progress,
                   file=sys.stderr, smoothing=0.1)
        last_flush = time.monotonic()
        try:
            with dask_client(client, scheduler, workers, allowed_failures, memory_limit) as dask:
                distributed = _import_distributed()
                futures = {}
                for i in todo:
                    future = dask.submit(_run_item, job, records[i].photo, records[i].output, options, files == "client",
                                         retries=retries, pure=False, key=f"facegeo-{kind}-{i}-{os.getpid()}-{time.time_ns()}")
                    futures[future] = i
                own_cluster = client is None and not scheduler
                completed = distributed.as_completed(list(futures))
                workerless_since: float | None = None
                try:
                    with _quiet_dask():
                        while futures:
                            ready = completed.next_batch(block=False)
                            if not ready:
                                workerless_since = _check_workers(dask, own_cluster, workerless_since, futures, records)
                                time.sleep(0.05)
                                continue
                            workerless_since = None
                            for future in ready:
                                _finish(future, futures, records, files, StagedOutput, bar, on_failure)
                            if time.monotonic() - last_flush > _FLUSH_SECONDS:
                                _write_reports(out, [r for r in records if r.status != "pending"], earlier)
                                last_flush = time.monotonic()
                    interrupted = False
                finally:
                    if futures:  # interrupted: nothing more runs for this batch
                        with _quiet_dask(), contextlib.suppress(Exception):
                            dask.cancel(list(futures), force=True)
        finally:
            bar.close()
            finished = [r for r in records if r.status != "pending"]
            _write_reports(out, finished, earlier)
            if not interrupted:  # no job of this batch runs any more: what is staged in OUT is left from killed workers
                remove_other_temporaries(out)
            elif client is None and not scheduler:  # the embedded workers were stopped; their staged folders are stale
                remove_stale_temporaries(out)
        return records


_NO_WORKER_SECONDS = 60.0  # the embedded cluster without a live worker this long: its nannies could not restart them


def _finish(future: Any, futures: dict[Any, int], records: list[BatchRecord], files: str, staged: Any, bar: Any,
            on_failure: Callable[[BatchRecord], None] | None) -> None:
    record = records[futures.pop(future)]
    _collect(record, future, files, staged)
    if record.status == "failed":
        bar.set_postfix_str(f"{sum(r.status == 'failed' for r in records)} failed")
        if on_failure is not None:
            on_failure(record)
    bar.update(1)


def _check_workers(dask: Any, own_cluster: bool, since: float | None, futures: dict[Any, int],
                   records: list[BatchRecord]) -> float | None:
    """While nothing completes: on the embedded cluster, fail what is left once no worker has
    been alive for :data:`_NO_WORKER_SECONDS` (a nanny whose restart failed, e.g. for want of
    memory, does not try again; a batch must end rather than wait for ever). An external
    cluster may be scaling, and is waited for."""
    if not own_cluster or dask.scheduler_info().get("workers"):
        return None
    now = time.monotonic()
    if since is None or now - since < _NO_WORKER_SECONDS:
        return since if since is not None else now
    for future, i in list(futures.items()):
        records[i].status = "failed"
        records[i].error = "no worker left: the embedded cluster's worker processes died and could not be restarted"
        future.cancel()
    futures.clear()
    return None


def _collect(record: BatchRecord, future: Any, files: str, staged: Any) -> None:
    """Fill ``record`` from a finished future (and, with ``files="client"``, write its files)."""
    from distributed import KilledWorker

    record.tries = 1
    try:
        outcome = future.result()
    except KilledWorker as exc:
        record.status, record.tries = "failed", exc.allowed_failures + 1
        record.error = (f"its job ended the worker process each of the {record.tries} times it ran "
                        "(a crash, or the worker's memory limit)")
        return
    except Exception as exc:  # an unexpected error on the worker, after Dask's retries
        record.status, record.error = "failed", _one_line(exc)
        return
    record.worker = outcome.get("worker", "")
    record.peak_memory_mib = outcome.get("peak_memory_mib")
    if "error" in outcome:
        record.status, record.error = "failed", outcome["error"]
        return
    job_record: JobRecord = outcome["record"]
    if "files" in outcome:
        with staged(record.output, replace=True) as stage:
            for name, data in outcome["files"].items():
                target = stage.path(name)
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(data)
    record.status = "done"
    record.job = job_record
    record.landmark_rms_px = job_record.landmark_rms_px
    record.landmark_rms_percent_iod = job_record.landmark_rms_percent_iod
    record.timings = dict(job_record.timings)


# ------------------------------------------------------------------------------------- API
def fit_many(photos: Iterable[str | os.PathLike[str]], out: str | os.PathLike[str], client: Any = None,
             options: FitOptions | None = None, *, workers: int | None = None, scheduler: str | None = None,
             resume: bool = False, retries: int = 2, allowed_failures: int = 2, files: str = "shared",
             job: Callable[..., JobRecord] | None = None, memory_limit: str | float | None = None,
             progress: bool | None = False, on_failure: Callable[[BatchRecord], None] | None = None) -> list[BatchRecord]:
    """Fit every photo of ``photos`` (paths, folders, globs, manifests: :func:`expand_inputs`)
    into ``out/<name>/`` (fit.json, mesh.obj, overlay.png) with ``options`` (default
    ``FitOptions()``), on ``client`` (an existing
    :class:`distributed.Client`, left open), on the cluster at ``scheduler``, or on an embedded
    ``LocalCluster`` of ``workers`` processes; returns one :class:`BatchRecord` per photo, in
    input order, and writes ``items.csv``, ``summary.csv`` and ``failures.csv`` into ``out``
    (see the module doc for the folder rules, ``resume``, ``files`` and the fault handling).

    Args:
        retries: re-runs of an item whose job raised something other than a FacegeoError.
        allowed_failures: worker deaths an item may cause before it is failed (embedded cluster).
        job: the per-item function ``job(photo, output, options) -> JobRecord`` (default
            :func:`facegeo.jobs.fit_into_folder`); it must be picklable and write ``output`` through
            :class:`~facegeo.staged_output.StagedOutput` with a ``fit.json``.
        memory_limit: per worker of the embedded cluster (bytes or "4GiB"; default: Dask's share).
        progress: a tqdm bar on stderr (None: only on a terminal).
        on_failure: called in the client with each failed photo's record as it fails.

    Raises:
        InputError: no inputs, an unusable ``out``, bad options, Dask missing, no scheduler.
        KeyboardInterrupt: passed on after the batch was cancelled and its reports written.
    """
    from facegeo.jobs import FitOptions

    return _run_many("fit", photos, out, client, options or FitOptions(), workers=workers, scheduler=scheduler, resume=resume,
                     retries=retries, allowed_failures=allowed_failures, files=files, job=job,
                     memory_limit=memory_limit, progress=progress, on_failure=on_failure)


def reconstruct_many(photos: Iterable[str | os.PathLike[str]], out: str | os.PathLike[str], client: Any = None,
                     options: ReconstructOptions | None = None, *, workers: int | None = None,
                     scheduler: str | None = None, resume: bool = False, retries: int = 2, allowed_failures: int = 2,
                     files: str = "shared", job: Callable[..., JobRecord] | None = None,
                     memory_limit: str | float | None = None, progress: bool | None = False,
                     on_failure: Callable[[BatchRecord], None] | None = None) -> list[BatchRecord]:
    """:func:`fit_many` with the whole pipeline per photo
    (:func:`facegeo.jobs.reconstruct_into_folder`: fit.json, the maps, the scenes, preview.png;
    ``options`` default ``ReconstructOptions()``)."""
    from facegeo.jobs import ReconstructOptions

    return _run_many("reconstruct", photos, out, client, options or ReconstructOptions(), workers=workers, scheduler=scheduler, resume=resume,
                     retries=retries, allowed_failures=allowed_failures, files=files, job=job,
                     memory_limit=memory_limit, progress=progress, on_failure=on_failure)
