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

If moving into an *existing* output folder fails half-way (a disk error while committing), the
files already moved stay and the rest are discarded; each file is still whole. A process killed
outright (SIGKILL, power loss) can leave a ``.facegeo-tmp-*`` folder behind; no file in the
output folder is ever partial.
"""

from __future__ import annotations

import errno
import os
import secrets
import shutil
import stat
from pathlib import Path
from types import TracebackType

from facegeo.errors import InputError

__all__ = ["StagedOutput", "atomic_write_bytes", "atomic_write_text", "TEMP_PREFIX"]

#: Name prefix of the hidden staging folders (and of atomic-write temporary files).
TEMP_PREFIX = ".facegeo-tmp-"


class StagedOutput:
    """Context manager that stages files and moves them into ``out_dir`` only on success.

    Usage::

        with StagedOutput(out_dir) as stage:
            np.save(stage.path("coeffs.npy"), coeffs)
            stage.path("fit.json").write_text(text)

    ``stage.path(name)`` returns where to write ``name`` (a relative path; sub-folders such as
    ``"textures/albedo.png"`` are allowed and created). Every regular file found in the staging
    folder at exit is moved, so writers that add side files (a ``.gltf`` with its ``.bin``) are
    covered too. Files in ``out_dir`` that the run did not write are kept; same-named ones are
    replaced.

    Raises (on entry):
        InputError: ``out_dir`` (or one of its parents) exists and is not a directory, or its
            parent folder is not writable.
    """

    def __init__(self, out_dir: str | os.PathLike[str]):
        self.out_dir = Path(out_dir)
        self._target: Path | None = None  # out_dir with symlinked parents resolved
        self._tmp: Path | None = None
        self._created_parents: list[Path] = []

    # -- context protocol --------------------------------------------------------------------

    def __enter__(self) -> StagedOutput:
        if self._tmp is not None:
            raise RuntimeError("StagedOutput is not re-entrant")
        source = str(self.out_dir)
        target = self.out_dir.resolve()
        if target.exists() and not target.is_dir():
            raise InputError(source, "output folder", "a directory", "an existing file")
        parent = target.parent
        self._created_parents = _make_parents(parent, source)
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
        except BaseException:
            self._rollback()
            raise
        else:
            if exc_type is not None:
                self._rollback()
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
        touched_dirs = {target}
        for f in files:
            dest = target / f.relative_to(tmp)
            if dest.is_dir() and not dest.is_symlink():
                raise InputError(str(dest), "output file", "a file path", "an existing directory")
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


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically: a temporary file in the same folder, fsync, replace.

    The folder must exist. An existing file keeps its permission bits; a new one gets the usual
    ``0o666 & ~umask``. Returns the path written.

    Raises:
        InputError: the folder is missing or not writable, or ``path`` is a directory.
    """
    target = Path(path)
    source = str(target)
    if target.is_dir():
        raise InputError(source, "output file", "a file path", "a directory")
    folder = target.parent
    if not folder.is_dir():
        raise InputError(source, "output file", "a path in an existing folder",
                         f"{folder} does not exist or is not a folder")
    try:
        existing_mode = stat.S_IMODE(target.stat().st_mode)
    except OSError:
        existing_mode = None

    tmp: Path | None = None
    try:
        fd, tmp = _open_temp_file(folder, target.name)
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
    _fsync(folder)
    return target


def atomic_write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> Path:
    """:func:`atomic_write_bytes` of ``text`` encoded with ``encoding`` (newlines written as is)."""
    return atomic_write_bytes(path, text.encode(encoding))


# -- helpers ---------------------------------------------------------------------------------


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


def _make_hidden_dir(parent: Path) -> Path:
    """Create ``parent/.facegeo-tmp-XXXXXXXX`` with the default (umask) permissions."""
    for _ in range(100):
        candidate = parent / f"{TEMP_PREFIX}{secrets.token_hex(4)}"
        try:
            os.mkdir(candidate)
        except FileExistsError:
            continue
        return candidate
    raise FileExistsError(errno.EEXIST, "no free temporary folder name", str(parent))  # pragma: no cover


def _open_temp_file(folder: Path, name: str) -> tuple[int, Path]:
    """Open a new file ``folder/.facegeo-tmp-<name>.XXXXXXXX`` (mode 0o666 & ~umask)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
    for _ in range(100):
        candidate = folder / f"{TEMP_PREFIX}{name}.{secrets.token_hex(4)}"
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
