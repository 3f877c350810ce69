"""Writing results so that nothing half-written is ever left behind, and nothing of the user's lost.

:class:`StagedOutput` collects all the files of one run in a hidden folder next to the output
folder and moves them in only when the run succeeded; :func:`atomic_write_bytes` and
:func:`atomic_write_text` replace a single file atomically; :func:`locked_output` holds the
output location's lock (:mod:`facegeo.output_lock`) for a whole run.

Guarantees (POSIX; the staging folder and the output folder on the same file system):

* **new output folder**: on success the whole staged folder is renamed into place at once;
* **existing output folder**: on success every staged file is moved in under its final name by
  ``os.replace``, so a reader sees the old file or the new one, never a partial one. The set of
  files changes during a commit of a few milliseconds, which is journalled: before the first
  move, the list of moves is written (fsync) into the staging folder, and every file it replaces
  or removes is kept there (a hard link) until the last move is done. An exception during the
  commit (a signal, a disk error) rolls every move back at once; a run *killed* during it
  (SIGKILL, power loss) leaves the folder mixed until the next facegeo run into the same place,
  which rolls it back from the journal before anything else (:func:`remove_stale_temporaries`).
  So the folder ends up as it was before the run or as the run wrote it, never between; the
  mix is visible only between a SIGKILL within the commit and the next run;
* **on an exception** before the commit (including KeyboardInterrupt) the staged files are
  deleted and the output folder is left exactly as it was: if it did not exist before, it does
  not exist afterwards (nor do parent folders created for it);
* **re-runs**, ``StagedOutput(out_dir, replace=True)`` (what the commands use for their output
  folder): the run writes the manifest :data:`MANIFEST` (the list of its files) last. A re-run
  into an earlier output replaces the files it writes again, removes the files of the earlier
  run (its manifest) that it does not write, and keeps every other file and folder untouched
  (the user's notes, a folder of the user's). An earlier output without a manifest (written
  before facegeo had one) loses only the files the new run writes again. An existing
  ``out_dir`` must be empty or an earlier facegeo output (it holds one of
  :data:`OUTPUT_MARKERS`); any other non-empty folder is refused (:class:`InputError`);
* **one run at a time**: ``replace=True`` (or ``lock=True``) holds the output folder's
  :class:`~facegeo.output_lock.OutputLock` from entry to exit (re-entrant: a job that holds it
  through :func:`locked_output` from its start keeps it); a second run into the same place is
  refused at once with an :class:`InputError` naming the other run's process;
* before any moving, every destination is checked (an existing folder where a file goes is
  refused), so a multi-file output is all or nothing;
* a write that fails for lack of room (ENOSPC, EFBIG, EDQUOT) or on a read-only or failing file
  system becomes one :class:`OutputError` naming the file, after the staged files are removed.

Temporary names are ``.facegeo-tmp-<pid>-h<host>-<random>`` (``<host>``: a hash of the host
name). A process killed outright (SIGKILL, power loss) leaves its ``.facegeo-tmp-*`` folder or
file (and its lock file) behind; the next :class:`StagedOutput`, :func:`locked_output` or
:func:`atomic_write_bytes` into the same place removes those of this host whose process no
longer exists (:func:`remove_stale_temporaries`), after rolling back an interrupted commit;
those of other hosts (batch workers sharing a file system) are left to their own host. No file
in the output folder is ever partial. The ``facegeo`` command turns SIGTERM and SIGINT into an
exception, so the clean-up above runs for them too.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import json
import os
import re
import secrets
import shutil
import stat
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import Callable, Iterable

from facegeo.errors import InputError, OutputError
from facegeo.output_lock import LOCK_PREFIX, OutputLock, host_name, make_parents, remove_created_parents, remove_stale_lock_file

__all__ = ["StagedOutput", "locked_output", "atomic_write_bytes", "atomic_write_text", "check_output_location",
           "scratch_folder", "remove_stale_temporaries", "remove_other_temporaries", "TEMP_PREFIX", "MANIFEST", "OUTPUT_MARKERS",
           "WRITE_FAULTS"]

#: Name prefix of the hidden staging folders (and of atomic-write temporary files).
TEMP_PREFIX = ".facegeo-tmp-"
#: The manifest a ``replace=True`` run writes into its output folder: the files it wrote, which a
#: re-run may replace or remove (JSON: ``{"files": [relative paths]}``).
MANIFEST = ".facegeo-output.json"
#: Files that mark a folder as an earlier facegeo output (``fit``/``reconstruct``, ``unwrap``,
#: an asset folder, any run with a manifest), into which ``StagedOutput(..., replace=True)`` may write.
OUTPUT_MARKERS = ("fit.json", "unwrap.json", "asset.json", MANIFEST)
#: Inside a staging folder: the journal of a commit into an existing folder (plan.json, old/).
_JOURNAL = TEMP_PREFIX + "commit"
_OWNER = re.compile(re.escape(TEMP_PREFIX) + r"(\d+)-(?:h([0-9a-f]{8})-)?")
#: errno values of writes that fail for want of room or of a working file system.
WRITE_FAULTS = {errno.ENOSPC: "no space left on the device", errno.EFBIG: "file too large for the file system or the process's file size limit",
                errno.EDQUOT: "disk quota exceeded", errno.EROFS: "read-only file system", errno.EIO: "input/output error"}
#: Faults that are the output's only on the output's own paths (a read elsewhere may raise them too).
OUTPUT_PATH_FAULTS = {errno.EACCES: "permission denied",
                      errno.EPERM: "the operation not permitted (an immutable or protected file or folder)"}


@contextlib.contextmanager
def locked_output(path: str | os.PathLike[str], field: str = "output folder") -> Iterator[OutputLock]:
    """Hold the lock of the output location ``path`` (a folder, or with ``field="output file"`` a
    file) for a whole run, so that a second run into it is refused at once, before any work.

    On entry, what killed runs left beside ``path`` is cleaned up first (an interrupted commit is
    rolled back: :func:`remove_stale_temporaries`). Missing parent folders are created for the
    lock file and removed on exit when still empty.

    Raises:
        InputError: another run holds the lock (naming ``path`` and that run's process id), or
            the lock file cannot be created.
    """
    with OutputLock(path, field) as lock:
        remove_stale_temporaries(lock.file.parent)
        yield lock


class StagedOutput:
    """Context manager that stages files and moves them into ``out_dir`` only on success.

    Usage::

        with StagedOutput(out_dir, replace=True) as stage:
            np.save(stage.path("coeffs.npy"), coeffs)
            stage.path("fit.json").write_text(text)

    ``stage.path(name)`` returns where to write ``name`` (a relative path; sub-folders such as
    ``"textures/albedo.png"`` are allowed and created). Every regular file found in the staging
    folder at exit is moved, so writers that add side files (a ``.gltf`` with its ``.bin``) are
    covered too.

    ``replace``: False (merge: same-named files in ``out_dir`` are replaced, all others kept) or
    True (a run's output folder: the earlier run's files that this run does not write are removed
    as well, and the manifest :data:`MANIFEST` is written; other files are kept; an existing
    non-empty ``out_dir`` without one of :data:`OUTPUT_MARKERS` is refused). ``lock``: hold the
    folder's :class:`~facegeo.output_lock.OutputLock` while staging and committing (default:
    ``replace``). See the module doc for the guarantees.

    Raises (on entry):
        InputError: ``out_dir`` (or one of its parents) exists and is not a directory, a name in
            it is too long, its parent folder is not writable, (``replace``) it is a non-empty
            folder that is not an earlier output, or (``lock``) another run writes into it.
        OutputError (at exit): a write failed for want of room or on a failing file system.
    """

    def __init__(self, out_dir: str | os.PathLike[str], *, replace: bool = False, lock: bool | None = None):
        self.out_dir = Path(out_dir)
        self.replace = replace
        self.lock = replace if lock is None else lock
        self._target: Path | None = None  # out_dir with symlinked parents resolved
        self._tmp: Path | None = None
        self._created_parents: list[Path] = []
        self._lock: OutputLock | None = None

    # -- context protocol --------------------------------------------------------------------

    def __enter__(self) -> StagedOutput:
        if self._tmp is not None:
            raise RuntimeError("StagedOutput is not re-entrant")
        source = str(self.out_dir)
        check_output_location(self.out_dir, folder=True, replace=self.replace)
        cleaned = False
        if self.lock:
            self._lock = OutputLock(self.out_dir, "output folder")
            cleaned = self._lock.held  # by locked_output, which took the lock first
            self._lock.acquire()
        try:
            self._stage(source, cleaned)
        except BaseException:
            self._release()
            raise
        return self

    def _stage(self, source: str, cleaned: bool) -> None:
        target = self.out_dir.resolve()
        parent = target.parent
        self._created_parents = make_parents(parent, source)
        if not cleaned:
            remove_stale_temporaries(parent)
        if target.is_dir():
            remove_stale_temporaries(target)
        if self.lock:  # under the lock: the folder as the earlier run left it
            check_output_location(self.out_dir, folder=True, replace=self.replace)
        try:
            if not os.access(parent, os.W_OK | os.X_OK):
                raise PermissionError(errno.EACCES, "permission denied", str(parent))
            self._tmp = _make_hidden_dir(parent)
        except OSError as exc:
            self._remove_created_parents()
            raise InputError(source, "output folder", "a location where files can be created",
                             f"{parent} is not writable ({exc.strerror or exc})") from None
        self._target = target

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> bool:
        try:
            if exc_type is None:
                self._commit()
        except BaseException as failure:
            self._rollback()
            fault = _as_output_error(failure, self.out_dir, self._tmp)
            if fault is not None:
                raise fault from None
            raise
        else:
            if exc_type is not None:
                self._rollback()
                fault = _as_output_error(exc, self.out_dir, self._tmp)
                if fault is not None:
                    raise fault from None
        finally:
            self._tmp = None
            self._release()
        return False  # never swallow the exception

    # -- API -------------------------------------------------------------------------------

    @property
    def staging_dir(self) -> Path:
        """The hidden folder files are written to (only inside the ``with`` block)."""
        if self._tmp is None:
            raise RuntimeError("StagedOutput.staging_dir is only available inside 'with'")
        return self._tmp

    def path(self, name: str | os.PathLike[str]) -> Path:
        """Where to write the output file ``name`` (relative, no ``..``); parents are created."""
        rel = Path(name)
        if (rel.is_absolute() or not rel.parts or any(part in ("..", ".") for part in rel.parts)
                or rel.parts[0] == _JOURNAL):
            raise ValueError(f"staged file name must be a plain relative path, got {str(name)!r}")
        path = self.staging_dir / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    # -- internals -----------------------------------------------------------------------

    def _commit(self) -> None:
        assert self._tmp is not None and self._target is not None
        tmp, target = self._tmp, self._target
        if self.replace:
            with contextlib.suppress(FileNotFoundError):
                (tmp / MANIFEST).unlink()  # a copied manifest (a batch's files sent back): written anew below
        for left in sorted(tmp.rglob(TEMP_PREFIX + "*"), reverse=True):  # a killed writer's scratch: never an output
            if left.is_dir() and not left.is_symlink():
                shutil.rmtree(left, ignore_errors=True)
            else:
                left.unlink(missing_ok=True)
        files = sorted(p.relative_to(tmp).as_posix() for p in tmp.rglob("*") if p.is_file() and not p.is_symlink())
        for f in files:
            _fsync(tmp / f)
        earlier: list[str] = []
        if self.replace:
            earlier = _manifest_files(target) if target.is_dir() else []
            (tmp / MANIFEST).write_text(_manifest_text(files))
            _fsync(tmp / MANIFEST)
            files.append(MANIFEST)  # moved last: a folder whose manifest is new holds the whole run
        if not target.exists():
            try:
                os.rename(tmp, target)  # the whole folder at once
            except OSError:
                pass  # appeared meanwhile (non-empty) or similar: fall back to per-file moves
            else:
                _fsync(target.parent)
                return
        if not target.is_dir():
            raise InputError(str(self.out_dir), "output folder", "a directory",
                             "an existing file (created while the run was going on)")
        if self.replace:
            check_output_location(self.out_dir, folder=True, replace=self.replace)  # still an earlier output?
        written = set(files)
        removed = [rel for rel in earlier if rel not in written and _inside(target, rel)
                   and (os.path.islink(target / rel) or (target / rel).is_file())]
        for rel in files:  # all checked before any is moved: all or nothing
            dest = target / rel
            if dest.is_dir() and not dest.is_symlink():
                raise InputError(str(dest), "output file", "a file path", "an existing directory")
            for folder in dest.relative_to(target).parents:
                if folder != Path(".") and (target / folder).exists() and not (target / folder).is_dir():
                    raise InputError(str(target / folder), "output folder", "a directory", "an existing file")
        _move_in(tmp, target, files, removed)
        shutil.rmtree(tmp, ignore_errors=True)

    def _rollback(self) -> None:
        if self._tmp is not None:
            _roll_back(self._tmp)  # moves already made (an interrupted commit) are undone first
        self._remove_created_parents()

    def _remove_created_parents(self) -> None:
        remove_created_parents(self._created_parents)
        self._created_parents = []

    def _release(self) -> None:
        if self._lock is not None:
            self._lock.release()
            self._lock = None


def check_output_location(path: str | os.PathLike[str], *, folder: bool, replace: bool = False,
                          extra_names: Iterable[str] = ()) -> None:
    """Check, before any work is done, that ``path`` can be written as an output folder
    (``folder=True``) or file.

    Checks: every path component fits the file system's NAME_MAX (bytes; ``extra_names``: names
    that will be created next to ``path``, e.g. ``face_textures``, checked too); no existing
    ancestor is a regular file; the nearest existing ancestor is a writable folder; an existing
    ``path`` has the right kind; with ``replace`` (see :class:`StagedOutput`), an existing
    non-empty folder holds one of :data:`OUTPUT_MARKERS`.

    Raises:
        InputError: naming ``path``, the field ("output folder" / "output file") and what was
            expected.
    """
    target = Path(path)
    source = str(target)
    field = "output folder" if folder else "output file"
    ancestor = target.absolute().parent  # where the staging folder or temporary file goes
    while not ancestor.exists() and ancestor.parent != ancestor:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise InputError(source, field, "a location inside a directory", f"{ancestor} (one of its parents) is a file")
    try:
        name_max = os.pathconf(ancestor, "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = 255
    for part in [*target.parts, *extra_names]:
        if len(os.fsencode(part)) > name_max:
            raise InputError(source, field, f"names of at most {name_max} bytes (the file system's NAME_MAX)",
                             f"a name of {len(os.fsencode(part))} bytes")
    if target.exists():
        if folder and not target.is_dir():
            raise InputError(source, field, "a directory", "an existing file")
        if not folder and target.is_dir():
            raise InputError(source, field, "a file path", "an existing directory")
        if folder and replace and target.resolve() in (Path.cwd(), *Path.cwd().parents):
            raise InputError(source, field, "a folder other than the current one and its parents (facegeo replaces files in it)",
                             f"{target.resolve()}")
        if folder and replace:
            entries = sorted(e.name for e in target.iterdir() if not e.name.startswith((TEMP_PREFIX, LOCK_PREFIX)))
            if entries and not any((target / m).is_file() for m in OUTPUT_MARKERS):
                raise InputError(source, field, f"a new or empty folder, or an earlier facegeo output (with {' or '.join(OUTPUT_MARKERS)})",
                                 f"a folder with other files ({', '.join(entries[:3])}{', ...' if len(entries) > 3 else ''})")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise InputError(source, field, "a location where files can be created", f"{ancestor} is not writable")


def _remove_temporaries(folder: str | os.PathLike[str], doomed: Callable[[str], bool]) -> list[Path]:
    """Delete the temporaries (names starting with :data:`TEMP_PREFIX`) in ``folder`` for whose
    name ``doomed`` is true, and the lock files no process holds; returns what was removed (what
    cannot be removed is left). A staging folder whose commit was interrupted is rolled back into
    its output folder first, under that folder's lock (left for later while another run holds it)."""
    removed: list[Path] = []
    try:
        entries = list(Path(folder).resolve().iterdir())
    except OSError:
        return removed
    for entry in entries:
        if entry.name.startswith(LOCK_PREFIX):
            if remove_stale_lock_file(entry):
                removed.append(entry)
            continue
        if not entry.name.startswith(TEMP_PREFIX) or not doomed(entry.name):
            continue
        try:
            if entry.is_dir() and not entry.is_symlink():
                if not _recover(entry):
                    continue
            else:
                entry.unlink()
        except OSError:
            continue
        removed.append(entry)
    return removed


def _stale(name: str) -> bool:
    match = _OWNER.match(name)
    return match is not None and match.group(2) in (None, _host()) and not _process_alive(int(match.group(1)))


@contextlib.contextmanager
def scratch_folder(parent: str | os.PathLike[str]) -> Iterator[Path]:
    """A new hidden folder in ``parent`` (``.facegeo-tmp-<pid>-h<host>-XXXXXXXX``) for files made on
    the way to an output, removed on exit. Beside the output rather than in the system's temporary
    folder: a process killed before its exit leaves it where the next run's
    :func:`remove_stale_temporaries` (or the staging folder's roll-back) removes it, and a staging
    folder's commit never moves it into the output."""
    folder = _make_hidden_dir(Path(parent))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def remove_stale_temporaries(folder: str | os.PathLike[str]) -> list[Path]:
    """Delete the ``.facegeo-tmp-<pid>-*`` folders and files in ``folder`` whose process no
    longer exists on this host (left by a run that was killed outright), after rolling back a
    commit such a run left half done, and the lock files no process holds; returns what was
    removed. Names without a process id, those of live processes and those of other hosts are
    left alone."""
    return _remove_temporaries(folder, _stale)


def remove_other_temporaries(folder: str | os.PathLike[str]) -> list[Path]:
    """Delete every temporary in ``folder`` but this process's own, whatever host or process
    wrote it (interrupted commits rolled back), and the lock files no process holds; returns what
    was removed. Only for a folder in which nothing else can be writing (a batch's output once
    none of its jobs runs: what is left there was left by dead workers)."""
    own = f"{TEMP_PREFIX}{os.getpid()}-"
    return _remove_temporaries(folder, lambda name: not name.startswith(own))


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically: a temporary file in the same folder, fsync, replace.

    The folder must exist. An existing file keeps its permission bits; a new one gets the usual
    ``0o666 & ~umask``. Stale temporaries of killed runs in the folder are removed first.
    Returns the path written.

    Raises:
        InputError: the folder is missing or not writable, or ``path`` is a directory.
        OutputError: the write failed for want of room or on a failing file system.
    """
    target = Path(path)
    source = str(target)
    if target.is_dir():
        raise InputError(source, "output file", "a file path", "a directory")
    folder = target.parent
    if not folder.is_dir():
        raise InputError(source, "output file", "a path in an existing folder",
                         f"{folder} does not exist or is not a folder")
    remove_stale_temporaries(folder)
    try:
        existing_mode = stat.S_IMODE(target.stat().st_mode)
    except OSError:
        existing_mode = None

    tmp: Path | None = None
    try:
        fd, tmp = _open_temp_file(folder)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            if existing_mode is not None:
                os.chmod(tmp, existing_mode)
            os.replace(tmp, target)
            tmp = None
        finally:
            if tmp is not None:
                try:
                    tmp.unlink()
                except OSError:
                    pass
    except PermissionError:
        raise InputError(source, "output file", "a writable location",
                         f"cannot create files in {folder} (permission denied)") from None
    except IsADirectoryError:
        raise InputError(source, "output file", "a file path", "a directory") from None
    except OSError as exc:
        fault = _as_output_error(exc, target)
        if fault is None:
            raise
        raise fault from None
    _fsync(folder)
    return target


def atomic_write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> Path:
    """:func:`atomic_write_bytes` of ``text`` encoded with ``encoding`` (newlines written as is)."""
    return atomic_write_bytes(path, text.encode(encoding))


# -- the commit into an existing folder, and its roll-back ------------------------------------


def _manifest_text(files: list[str]) -> str:
    return json.dumps({"about": "the files the last facegeo run wrote into this folder; a re-run replaces or removes "
                       "these and keeps every other file", "files": files}, indent=1) + "\n"


def _manifest_files(folder: Path) -> list[str]:
    """The files an earlier run listed in ``folder``'s manifest ([] without a readable one)."""
    try:
        files = json.loads((folder / MANIFEST).read_text(encoding="utf-8")).get("files", [])
    except (OSError, ValueError, AttributeError):
        return []
    return [f for f in files if isinstance(f, str)] if isinstance(files, list) else []


def _inside(folder: Path, rel: str) -> bool:
    """Whether ``rel`` names a file inside ``folder`` itself: relative, no ``..``, no temporary or
    lock name, no symlinked folder on the way (a manifest is a file the user can edit)."""
    path = Path(rel)
    if (not rel or path.is_absolute() or any(p in ("", ".", "..") for p in path.parts)
            or path.parts[0].startswith((TEMP_PREFIX, LOCK_PREFIX))):
        return False
    return (folder / path).parent.resolve() == folder.resolve() / path.parent


def _move_in(tmp: Path, target: Path, written: list[str], removed: list[str]) -> None:
    """Move the staged files ``written`` from ``tmp`` into the existing folder ``target`` and
    remove the earlier run's files ``removed`` from it, journalled in ``tmp/_JOURNAL``: the plan
    first, the replaced and removed files kept (hard links) until the end. Any exception rolls
    every move back (:func:`_roll_back`); the plan is deleted last, the commit point."""
    journal = tmp / _JOURNAL
    needed = sorted({d for rel in written for d in Path(rel).parents if d != Path(".")}, key=lambda d: len(d.parts))
    created = [d.as_posix() for d in needed if not (target / d).exists()]
    journal.mkdir()
    part = journal / "plan.part"
    part.write_text(json.dumps({"target": target.name, "written": written, "removed": removed, "created": created}))
    _fsync(part)
    os.rename(part, journal / "plan.json")
    _fsync(journal)
    old = journal / "old"
    touched = {target}
    try:
        for d in created:
            (target / d).mkdir(exist_ok=True)
        for rel in written:
            dest = target / rel
            if os.path.lexists(dest):
                _keep(dest, old / rel, link=True)
            os.replace(tmp / rel, dest)
            touched.add(dest.parent)
        for rel in removed:
            dest = target / rel
            _keep(dest, old / rel, link=False)
            touched.add(dest.parent)
            for folder in dest.relative_to(target).parents:  # folders the earlier run's files leave empty
                if folder == Path("."):
                    break
                try:
                    (target / folder).rmdir()
                except OSError:
                    break
        for d in touched:
            _fsync(d)
        os.unlink(journal / "plan.json")  # the commit point
        _fsync(journal)
    except BaseException:
        _roll_back(tmp)
        raise


def _keep(path: Path, backup: Path, link: bool) -> None:
    """Keep ``path`` as ``backup`` for a roll-back: a hard link (``link``: ``path`` stays, to be
    replaced) or a move; a file system without hard links gets a move."""
    backup.parent.mkdir(parents=True, exist_ok=True)
    if link:
        try:
            os.link(path, backup, follow_symlinks=False)
            return
        except OSError:
            pass
    os.rename(path, backup)


def _roll_back(tmp: Path) -> bool:
    """Undo what a commit from the staging folder ``tmp`` did to its output folder (nothing when it
    did not start or was completed) and delete ``tmp``; False (``tmp`` left) when its journal
    cannot be read."""
    plan_file = tmp / _JOURNAL / "plan.json"
    if plan_file.exists():
        try:
            plan = json.loads(plan_file.read_text(encoding="utf-8"))
            target = tmp.parent / plan["target"]
            written, removed, created = plan["written"], plan["removed"], plan["created"]
        except (OSError, ValueError, KeyError, TypeError):
            return False
        old = tmp / _JOURNAL / "old"
        for rel in removed:
            if _inside(target, rel) and os.path.lexists(old / rel) and not os.path.lexists(target / rel):
                (target / rel).parent.mkdir(parents=True, exist_ok=True)
                os.rename(old / rel, target / rel)
        for rel in written:
            if not _inside(target, rel):
                continue
            dest = target / rel
            if os.path.lexists(old / rel):  # it replaced (or was about to replace) an earlier file
                os.replace(old / rel, dest)
            elif not os.path.lexists(tmp / rel) and os.path.lexists(dest):  # moved in, nothing before
                dest.unlink()
        for d in reversed(created):
            with contextlib.suppress(OSError):
                (target / d).rmdir()
        _fsync(target)
    shutil.rmtree(tmp, ignore_errors=True)
    return True


def _recover(staging: Path) -> bool:
    """Remove a dead run's staging folder; one with an interrupted commit is rolled back first,
    holding its output folder's lock (False, left as it is, while another run holds that lock)."""
    plan_file = staging / _JOURNAL / "plan.json"
    if not plan_file.exists():
        shutil.rmtree(staging)
        return True
    try:
        name = json.loads(plan_file.read_text(encoding="utf-8"))["target"]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    lock = OutputLock(staging.parent / name)
    if not lock.try_acquire():
        return False
    try:
        return _roll_back(staging)
    finally:
        lock.release()


# -- helpers ---------------------------------------------------------------------------------


@functools.cache
def _host() -> str:
    """8 hex digits naming this host in temporary names: processes of other hosts writing to a
    shared file system cannot be checked by process id, so their temporaries are never taken for
    stale ones."""
    return hashlib.sha1(host_name().encode("utf-8", "replace")).hexdigest()[:8]


def _as_output_error(exc: BaseException | None, out: Path, staging: Path | None = None) -> OutputError | None:
    """The :class:`OutputError` for a write fault (ENOSPC, EFBIG, ... or an OutputError raised
    deeper), naming the final output path rather than the staging one; None for anything else."""
    if isinstance(exc, OutputError):
        path, problem = Path(exc.path), exc.problem
    elif isinstance(exc, OSError) and exc.errno in WRITE_FAULTS:
        path, problem = Path(exc.filename or out), WRITE_FAULTS[exc.errno]
    elif (isinstance(exc, OSError) and exc.errno in OUTPUT_PATH_FAULTS and exc.filename is not None
          and any(_within(Path(exc.filename), folder) for folder in (out, staging) if folder is not None)):
        path, problem = Path(exc.filename), OUTPUT_PATH_FAULTS[exc.errno]
    else:
        return None
    if staging is not None:
        try:
            path = out / path.relative_to(staging)
        except ValueError:
            pass
    return OutputError(path, problem)


def _within(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or lies inside it (both resolved as far as they exist)."""
    path, folder = Path(os.path.realpath(path)), Path(os.path.realpath(folder))
    return path == folder or folder in path.parents


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # exists, owned by someone else
    return True


def _temp_name() -> str:
    """``.facegeo-tmp-<pid>-h<host>-<random>``: the process id and host let a later run tell a
    stale one."""
    return f"{TEMP_PREFIX}{os.getpid()}-h{_host()}-{secrets.token_hex(4)}"


def _make_hidden_dir(parent: Path) -> Path:
    """Create ``parent/.facegeo-tmp-<pid>-h<host>-XXXXXXXX`` with the default (umask) permissions."""
    for _ in range(100):
        candidate = parent / _temp_name()
        try:
            os.mkdir(candidate)
        except FileExistsError:
            continue
        return candidate
    raise FileExistsError(errno.EEXIST, "no free temporary folder name", str(parent))  # pragma: no cover


def _open_temp_file(folder: Path) -> tuple[int, Path]:
    """Open a new file ``folder/.facegeo-tmp-<pid>-h<host>-XXXXXXXX`` (mode 0o666 & ~umask); the name
    does not repeat the target's, so a target name of NAME_MAX bytes still works."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
    for _ in range(100):
        candidate = folder / _temp_name()
        try:
            return os.open(candidate, flags, 0o666), candidate
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary file name", str(folder))  # pragma: no cover


def _fsync(path: Path) -> None:
    """Flush a file's data, or make renames in a folder durable (best effort: not every OS can
    fsync a folder)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
