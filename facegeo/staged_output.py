"""Writing results so that nothing half-written is ever left behind.

:class:`StagedOutput` collects all the files of one run in a hidden folder next to the output
folder and moves them in only when the run succeeded; :func:`atomic_write_bytes` and
:func:`atomic_write_text` replace a single file atomically.

Guarantees (POSIX; the temporary folder and the target are on the same file system):

* on success every staged file appears in the output folder under its final name, each one
  atomically (``os.replace``): a reader sees the old file or the new one, never a partial one;
  when the output folder did not exist, the whole staged folder is renamed into place at once;
* on an exception (including KeyboardInterrupt) the staged files are deleted and the output
  folder is left exactly as it was: if it did not exist before, it does not exist afterwards
  (nor do parent folders created for it).

* ``StagedOutput(out_dir, replace=True)`` (what the commands use for their output folder):
  ``out_dir`` ends up holding exactly this run's files. An existing ``out_dir`` must be empty or
  an earlier facegeo output (it holds one of :data:`OUTPUT_MARKERS`); it is swapped out by two
  renames and deleted after the commit. Any other non-empty folder is refused
  (:class:`InputError`), so a mistyped ``-o ~`` can never delete a user's files.
* before any moving, every destination is checked (an existing folder where a file goes is
  refused), so a multi-file output is all or nothing; if moving into an *existing* folder in
  merge mode fails half-way (a disk error while committing), the files already moved stay and
  the rest are discarded; each file is still whole;
* a write that fails for lack of room (ENOSPC, EFBIG, EDQUOT) or on a read-only or failing file
  system becomes one :class:`OutputError` naming the file, after the staged files are removed.

Temporary names are ``.facegeo-tmp-<pid>-h<host>-<random>`` (``<host>``: a hash of the host
name). A process killed outright (SIGKILL, power loss) leaves its ``.facegeo-tmp-*`` folder or
file behind; the next :class:`StagedOutput` or :func:`atomic_write_bytes` into the same place
removes those of this host whose process no longer exists (:func:`remove_stale_temporaries`);
those of other hosts (batch workers sharing a file system) are left to their own host. No file in the output folder is ever
partial. The ``facegeo`` command turns SIGTERM and SIGINT into an exception, so the clean-up
above runs for them too.
"""

from __future__ import annotations

import errno
import hashlib
import os
import re
import secrets
import shutil
import socket
import stat
from pathlib import Path
from types import TracebackType
from typing import Callable, Iterable

from facegeo.errors import InputError, OutputError

__all__ = ["StagedOutput", "atomic_write_bytes", "atomic_write_text", "check_output_location",
           "remove_stale_temporaries", "remove_other_temporaries", "TEMP_PREFIX", "OUTPUT_MARKERS", "WRITE_FAULTS"]

#: Name prefix of the hidden staging folders (and of atomic-write temporary files).
TEMP_PREFIX = ".facegeo-tmp-"
#: Files that mark a folder as an earlier facegeo output (``fit``/``reconstruct``, ``unwrap``,
#: an asset folder), which ``StagedOutput(..., replace=True)`` may replace as a whole.
OUTPUT_MARKERS = ("fit.json", "unwrap.json", "asset.json")
_OWNER = re.compile(re.escape(TEMP_PREFIX) + r"(\d+)-(?:h([0-9a-f]{8})-)?")
#: This host in temporary names: processes of other hosts writing to a shared file system
#: cannot be checked by process id, so their temporaries are never taken for stale ones.
_HOST = hashlib.sha1(socket.gethostname().encode("utf-8", "replace")).hexdigest()[:8]
#: errno values of writes that fail for want of room or of a working file system.
WRITE_FAULTS = {errno.ENOSPC: "no space left on the device", errno.EFBIG: "file too large for the file system or the process's file size limit",
                errno.EDQUOT: "disk quota exceeded", errno.EROFS: "read-only file system", errno.EIO: "input/output error"}


class StagedOutput:
    """Context manager that stages files and moves them into ``out_dir`` only on success.

    Usage::

        with StagedOutput(out_dir) as stage:
            np.save(stage.path("coeffs.npy"), coeffs)
            stage.path("fit.json").write_text(text)

    ``stage.path(name)`` returns where to write ``name`` (a relative path; sub-folders such as
    ``"textures/albedo.png"`` are allowed and created). Every regular file found in the staging
    folder at exit is moved, so writers that add side files (a ``.gltf`` with its ``.bin``) are
    covered too.

    ``replace``: False (merge: files in ``out_dir`` that the run did not write are kept,
    same-named ones are replaced) or True: ``out_dir`` then holds exactly this run's files
    afterwards, and an existing non-empty ``out_dir`` without one of :data:`OUTPUT_MARKERS`
    (i.e. not an earlier facegeo output) is refused.

    Raises (on entry):
        InputError: ``out_dir`` (or one of its parents) exists and is not a directory, a name in
            it is too long, its parent folder is not writable, or (``replace``) it is a non-empty
            folder that is not an earlier output.
        OutputError (at exit): a write failed for want of room or on a failing file system.
    """

    def __init__(self, out_dir: str | os.PathLike[str], *, replace: bool = False):
        self.out_dir = Path(out_dir)
        self.replace = replace
        self._target: Path | None = None  # out_dir with symlinked parents resolved
        self._tmp: Path | None = None
        self._created_parents: list[Path] = []

    # -- context protocol --------------------------------------------------------------------

    def __enter__(self) -> StagedOutput:
        if self._tmp is not None:
            raise RuntimeError("StagedOutput is not re-entrant")
        source = str(self.out_dir)
        check_output_location(self.out_dir, folder=True, replace=self.replace)
        target = self.out_dir.resolve()
        parent = target.parent
        self._created_parents = _make_parents(parent, source)
        remove_stale_temporaries(parent)
        if target.is_dir():
            remove_stale_temporaries(target)
        try:
            if not os.access(parent, os.W_OK | os.X_OK):
                raise PermissionError(errno.EACCES, "permission denied", str(parent))
            self._tmp = _make_hidden_dir(parent)
        except OSError as exc:
            self._remove_created_parents()
            raise InputError(source, "output folder", "a location where files can be created",
                             f"{parent} is not writable ({exc.strerror or exc})") from None
        self._target = target
        return self

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
        if rel.is_absolute() or not rel.parts or any(part in ("..", ".") for part in rel.parts):
            raise ValueError(f"staged file name must be a plain relative path, got {str(name)!r}")
        path = self.staging_dir / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    # -- internals -----------------------------------------------------------------------

    def _commit(self) -> None:
        assert self._tmp is not None and self._target is not None
        tmp, target = self._tmp, self._target
        files = sorted(p for p in tmp.rglob("*") if p.is_file() and not p.is_symlink())
        for f in files:
            _fsync(f)
        if self.replace and target.is_dir():
            check_output_location(self.out_dir, folder=True, replace=self.replace)  # still an earlier output?
            old = target.parent / _temp_name()
            os.rename(target, old)  # from here on the old output is a temporary until deleted
            try:
                os.rename(tmp, target)
            except BaseException:
                os.rename(old, target)
                raise
            _fsync(target.parent)
            shutil.rmtree(old, ignore_errors=True)
            return
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
        moves = [(f, target / f.relative_to(tmp)) for f in files]
        for _, dest in moves:  # all checked before any is moved: all or nothing
            if dest.is_dir() and not dest.is_symlink():
                raise InputError(str(dest), "output file", "a file path", "an existing directory")
        touched_dirs = {target}
        for f, dest in moves:
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.replace(f, dest)
            touched_dirs.add(dest.parent)
        for d in touched_dirs:
            _fsync(d)
        shutil.rmtree(tmp, ignore_errors=True)

    def _rollback(self) -> None:
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
        self._remove_created_parents()

    def _remove_created_parents(self) -> None:
        for d in self._created_parents:  # deepest first
            try:
                d.rmdir()
            except OSError:
                break
        self._created_parents = []


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
            raise InputError(source, field, "a folder other than the current one and its parents (it is replaced as a whole)",
                             f"{target.resolve()}")
        if folder and replace:
            entries = sorted(e.name for e in target.iterdir() if not e.name.startswith(TEMP_PREFIX))
            if entries and not any((target / m).is_file() for m in OUTPUT_MARKERS):
                raise InputError(source, field, f"a new or empty folder, or an earlier facegeo output (with {' or '.join(OUTPUT_MARKERS)})",
                                 f"a folder with other files ({', '.join(entries[:3])}{', ...' if len(entries) > 3 else ''})")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise InputError(source, field, "a location where files can be created", f"{ancestor} is not writable")


def _remove_temporaries(folder: str | os.PathLike[str], doomed: Callable[[str], bool]) -> list[Path]:
    """Delete the temporaries (names starting with :data:`TEMP_PREFIX`) in ``folder`` for whose
    name ``doomed`` is true; returns what was removed (what cannot be removed is left)."""
    removed: list[Path] = []
    try:
        entries = list(Path(folder).iterdir())
    except OSError:
        return removed
    for entry in entries:
        if not entry.name.startswith(TEMP_PREFIX) or not doomed(entry.name):
            continue
        try:
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
        except OSError:
            continue
        removed.append(entry)
    return removed


def _stale(name: str) -> bool:
    match = _OWNER.match(name)
    return match is not None and match.group(2) in (None, _HOST) and not _process_alive(int(match.group(1)))


def remove_stale_temporaries(folder: str | os.PathLike[str]) -> list[Path]:
    """Delete the ``.facegeo-tmp-<pid>-*`` folders and files in ``folder`` whose process no
    longer exists on this host (left by a run that was killed outright); returns what was
    removed. Names without a process id, those of live processes and those of other hosts are
    left alone."""
    return _remove_temporaries(folder, _stale)


def remove_other_temporaries(folder: str | os.PathLike[str]) -> list[Path]:
    """Delete every temporary in ``folder`` but this process's own, whatever host or process
    wrote it; returns what was removed. Only for a folder in which nothing else can be writing
    (a batch's output once none of its jobs runs: what is left there was left by dead workers)."""
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


# -- helpers ---------------------------------------------------------------------------------


def _as_output_error(exc: BaseException | None, out: Path, staging: Path | None = None) -> OutputError | None:
    """The :class:`OutputError` for a write fault (ENOSPC, EFBIG, ... or an OutputError raised
    deeper), naming the final output path rather than the staging one; None for anything else."""
    if isinstance(exc, OutputError):
        path, problem = Path(exc.path), exc.problem
    elif isinstance(exc, OSError) and exc.errno in WRITE_FAULTS:
        path, problem = Path(exc.filename or out), WRITE_FAULTS[exc.errno]
    else:
        return None
    if staging is not None:
        try:
            path = out / path.relative_to(staging)
        except ValueError:
            pass
    return OutputError(path, problem)


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


def _make_parents(folder: Path, source: str) -> list[Path]:
    """Create ``folder`` and missing ancestors; return the ones created, deepest first."""
    missing: list[Path] = []
    d = folder
    while not d.exists():
        missing.append(d)
        if d.parent == d:
            break
        d = d.parent
    if d.exists() and not d.is_dir():
        raise InputError(source, "output folder", "a directory",
                         f"{d} (one of its parent folders) is a file")
    created: list[Path] = []
    for m in reversed(missing):
        try:
            m.mkdir()
        except FileExistsError:
            continue
        except OSError as exc:
            for c in reversed(created):
                try:
                    c.rmdir()
                except OSError:
                    break
            raise InputError(source, "output folder", "a location where folders can be created",
                             f"cannot create {m} ({exc.strerror or exc})") from None
        created.append(m)
    return list(reversed(created))


def _temp_name() -> str:
    """``.facegeo-tmp-<pid>-h<host>-<random>``: the process id and host let a later run tell a
    stale one."""
    return f"{TEMP_PREFIX}{os.getpid()}-h{_HOST}-{secrets.token_hex(4)}"


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
