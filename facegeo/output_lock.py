"""One facegeo run at a time per output location: an advisory lock file beside the output.

:class:`OutputLock` holds ``fcntl.flock`` on ``<parent>/.facegeo-lock-<name>`` (the output
folder's or file's name; a hash of it when that name would exceed NAME_MAX) for as long as a
run writes ``<parent>/<name>``. The file holds the holder's process id and host name, so that a
second run into the same place fails at once with one :class:`~facegeo.errors.InputError` that
names the output and the other run's process.

Guarantees and limits:

* the lock is advisory: it excludes facegeo runs (commands, jobs, batches, the Python API through
  :class:`~facegeo.staged_output.StagedOutput`), not other programs;
* the kernel releases a ``flock`` when its process dies, however it dies (SIGKILL, a crash), so a
  lock left by a killed run is stale by construction: the next run takes it over; its file stays
  until a facegeo run writes into that folder again (it is then removed,
  :func:`remove_stale_lock_file`);
* a run removes its lock file when it ends (unlinked while still locked; a run that opened the
  old file checks after locking that the name still refers to the file it locked, and tries
  again if not), so a finished run leaves no file behind;
* re-entrant per thread: a job that holds the lock of its output folder may open a
  :class:`~facegeo.staged_output.StagedOutput` into it; another thread of the same process is
  refused like another process. A child created by ``fork`` does not keep its parent's locks;
* on NFS, Linux maps ``flock`` onto POSIX byte-range locks, which the server arbitrates between
  hosts; the pid is then qualified with the host name in the message. On a file system that
  cannot lock at all (``flock`` fails with ENOLCK, EINVAL, ...) runs go on unguarded, as before
  locks existed.
"""

from __future__ import annotations

import errno
import fcntl
import functools
import hashlib
import os
import threading
import time
from pathlib import Path
from types import TracebackType

from facegeo.errors import InputError

__all__ = ["OutputLock", "LOCK_PREFIX", "lock_file", "make_parents", "remove_created_parents", "remove_stale_lock_file", "host_name"]

#: Name prefix of the lock files.
LOCK_PREFIX = ".facegeo-lock-"


@functools.cache
def host_name() -> str:
    """This host's name, as ``socket.gethostname`` gives it: on POSIX ``uname``'s node name, which
    is what it returns (without importing socket, 15 ms of every command's start)."""
    if hasattr(os, "uname"):
        return os.uname().nodename
    import socket  # pragma: no cover - not POSIX

    return socket.gethostname()  # pragma: no cover


#: (thread id, lock file) -> [file descriptor, depth, parents created for it]
_HELD: dict[tuple[int, Path], list] = {}
_HELD_GUARD = threading.Lock()


def _forget_locks_in_child() -> None:
    """After fork: the child must not keep its parent's locks alive (a flock lives as long as any
    descriptor of its open file does), so it closes its copies."""
    for fd, _, _ in _HELD.values():
        try:
            os.close(fd)
        except OSError:
            pass
    _HELD.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_locks_in_child)


def lock_file(path: str | os.PathLike[str]) -> Path:
    """The lock file of the output ``path`` (folder or file): ``.facegeo-lock-<name>`` beside the
    resolved path, or ``.facegeo-lock-<sha1 of the name>`` when the name is too long for that."""
    target = Path(path).resolve()
    name = LOCK_PREFIX + target.name
    if len(os.fsencode(name)) > 255:
        name = LOCK_PREFIX + hashlib.sha1(os.fsencode(target.name)).hexdigest()
    return target.parent / name


def make_parents(folder: Path, source: str, field: str = "output folder") -> list[Path]:
    """Create ``folder`` and its missing ancestors; return the ones created, deepest first.

    Raises:
        InputError: naming ``source`` and ``field``, when an ancestor is a file or a folder cannot
            be created (what was created is removed again).
    """
    missing: list[Path] = []
    d = folder
    while not d.exists():
        missing.append(d)
        if d.parent == d:
            break
        d = d.parent
    if d.exists() and not d.is_dir():
        raise InputError(source, field, "a directory", f"{d} (one of its parent folders) is a file")
    created: list[Path] = []
    for m in reversed(missing):
        try:
            m.mkdir()
        except FileExistsError:
            continue
        except OSError as exc:
            remove_created_parents(list(reversed(created)))
            raise InputError(source, field, "a location where folders can be created",
                             f"cannot create {m} ({exc.strerror or exc})") from None
        created.append(m)
    return list(reversed(created))


def remove_created_parents(created: list[Path]) -> None:
    """Remove the folders of ``created`` (deepest first) while they are empty."""
    for d in created:
        try:
            d.rmdir()
        except OSError:
            break


#: flock's answers when another open file holds the lock.
_BUSY = (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES)


def _lock_or_holder(fd: int) -> str | None:
    """``flock`` ``fd`` (exclusive, not waiting): None when locked, else the text the holder wrote
    (its process id and host; '' when it wrote none within a second).

    A holder writes its record just after locking, so an empty file is tried again for a moment:
    it is either a run about to write, or :func:`remove_stale_lock_file` in another run, which
    holds the lock of a file it found (maybe one this run has just created) for microseconds and
    writes nothing. Without the second try a batch item was refused now and then while another
    item's run cleaned the same folder.

    Raises:
        OSError: ``flock`` failing otherwise (a file system that cannot lock).
    """
    deadline = time.monotonic() + 1.0
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return None
        except OSError as exc:
            if exc.errno not in _BUSY:
                raise
        try:
            text = os.pread(fd, 256, 0).decode("utf-8", "replace").strip()
        except OSError:
            text = ""
        if text or time.monotonic() > deadline:
            return text
        time.sleep(0.005)


def _owner_text(text: str) -> str:
    """'one running (process 1234)' (or '... on host h') from a holder's record."""
    fields = text.split(maxsplit=1)
    if not fields or not fields[0].isdigit():
        return "one running (process unknown)"
    host = fields[1] if len(fields) > 1 else ""
    where = "" if host in ("", host_name()) else f" on host {host}"
    return f"one running (process {fields[0]}{where})"


def _same_file(fd: int, path: Path) -> bool:
    """Whether ``path`` still names the open file ``fd`` (it may have been unlinked and made anew)."""
    try:
        named = os.stat(path)
    except OSError:
        return False
    held = os.fstat(fd)
    return (named.st_dev, named.st_ino) == (held.st_dev, held.st_ino)


class OutputLock:
    """Context manager holding the advisory lock of the output location ``path`` (see the module doc).

    ``field`` names the kind of output in the error ("output folder" / "output file").
    Missing parent folders of ``path`` are created for the lock file and removed again on release
    when they are still empty (nothing was written).

    Raises (on entry):
        InputError: another run holds the lock (naming ``path`` and its process), or the lock
            file cannot be created (an ancestor is a file, the folder is not writable).
    """

    def __init__(self, path: str | os.PathLike[str], field: str = "output folder"):
        self.path = Path(path)
        self.field = field
        self.file = lock_file(self.path)
        self._key = (threading.get_ident(), self.file)
        self._busy_owner = ""  # who holds it, after a refused try

    def __enter__(self) -> OutputLock:
        self.acquire()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.release()

    def acquire(self) -> None:
        """Take the lock or raise :class:`InputError` at once (no waiting)."""
        if not self.try_acquire():
            raise InputError(str(self.path), self.field, "no other facegeo run writing to it at the same time",
                             self._busy_owner)

    def try_acquire(self) -> bool:
        """Take the lock if no other run holds it; False (nothing changed) otherwise."""
        with _HELD_GUARD:
            held = _HELD.get(self._key)
            if held is not None:
                held[1] += 1
                return True
        created = make_parents(self.file.parent, str(self.path), self.field)
        try:
            fd = self._lock_fd()
        except BaseException:
            remove_created_parents(created)
            raise
        if fd is None:
            remove_created_parents(created)
            return False
        record = f"{os.getpid()} {host_name()}\n".encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, record, 0)
        with _HELD_GUARD:
            _HELD[self._key] = [fd, 1, created]
        return True

    def _lock_fd(self) -> int | None:
        """A descriptor of the lock file, flock'ed, whose name still refers to it; None when held."""
        flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0)
        for _ in range(100):
            try:
                fd = os.open(self.file, flags, 0o666)
            except OSError as exc:
                raise InputError(str(self.path), self.field, "a location where files can be created",
                                 f"{self.file.parent} is not writable ({exc.strerror or exc})") from None
            try:
                holder = _lock_or_holder(fd)
            except OSError:
                return fd  # a file system without locks (ENOLCK, EINVAL, ...): the run goes on unguarded
            if holder is not None:
                self._busy_owner = _owner_text(holder)
                os.close(fd)
                return None
            if _same_file(fd, self.file):
                return fd
            os.close(fd)  # unlinked by its last holder meanwhile: lock the file now under that name
        raise InputError(str(self.path), self.field, "a lock file that stays in place",  # pragma: no cover
                         f"{self.file} replaced 100 times while locking")

    def release(self) -> None:
        """Give the lock back (the outermost release of this thread removes the lock file)."""
        with _HELD_GUARD:
            held = _HELD.get(self._key)
            if held is None:
                return
            held[1] -= 1
            if held[1] > 0:
                return
            del _HELD[self._key]
        fd, _, created = held
        try:
            os.unlink(self.file)  # still locked: a run that opened it will see it gone and retry
        except OSError:
            pass
        os.close(fd)
        remove_created_parents(created)

    @property
    def held(self) -> bool:
        """Whether this thread holds the lock."""
        return self._key in _HELD


def remove_stale_lock_file(path: str | os.PathLike[str]) -> bool:
    """Delete the lock file ``path`` if no process holds it (left by a killed run); True when
    removed. One held by a live run, this process's included, is left (and so is any on a file
    system that cannot lock)."""
    entry = Path(path)
    with _HELD_GUARD:
        if any(held == entry for _, held in _HELD):
            return False
    try:
        fd = os.open(entry, os.O_RDWR | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if _same_file(fd, entry):
            os.unlink(entry)
            return True
    except OSError:
        pass
    finally:
        os.close(fd)
    return False
