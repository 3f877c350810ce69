"""Tests of facegeo.staged_output: results appear whole or not at all."""

from __future__ import annotations

import os
import stat

import pytest

from facegeo.errors import InputError, OutputError
from facegeo.staged_output import TEMP_PREFIX, StagedOutput, atomic_write_bytes, atomic_write_text


class Boom(Exception):
    pass


def listing(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_success_moves_all_files(tmp_path):
    out = tmp_path / "result"
    with StagedOutput(out) as stage:
        stage.path("fit.json").write_text("{}")
        stage.path("textures/albedo.png").write_bytes(b"png")
        (stage.staging_dir / "mesh.bin").write_bytes(b"side file")  # written by some exporter
        assert stage.staging_dir.parent == tmp_path
        assert stage.staging_dir.name.startswith(TEMP_PREFIX)
        assert not out.exists()  # nothing visible before the end
    assert listing(out) == ["fit.json", "mesh.bin", "textures", "textures/albedo.png"]
    assert (out / "fit.json").read_text() == "{}"
    assert [p.name for p in tmp_path.iterdir()] == ["result"]  # no temp folder left


def test_new_output_dir_has_normal_permissions(tmp_path):
    out = tmp_path / "result"
    with StagedOutput(out) as stage:
        stage.path("a.txt").write_text("a")
    reference = tmp_path / "reference"
    reference.mkdir()
    assert stat.S_IMODE(out.stat().st_mode) == stat.S_IMODE(reference.stat().st_mode)


def test_exception_leaves_nothing(tmp_path):
    out = tmp_path / "result"
    with pytest.raises(Boom):
        with StagedOutput(out) as stage:
            stage.path("fit.json").write_text("{}")
            stage.path("sub/x.txt").write_text("x")
            raise Boom()
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_exception_removes_created_parents(tmp_path):
    out = tmp_path / "a" / "b" / "result"
    with pytest.raises(Boom):
        with StagedOutput(out) as stage:
            stage.path("fit.json").write_text("{}")
            raise Boom()
    assert list(tmp_path.iterdir()) == []


def test_keyboard_interrupt_leaves_nothing(tmp_path):
    out = tmp_path / "result"
    with pytest.raises(KeyboardInterrupt):
        with StagedOutput(out) as stage:
            stage.path("fit.json").write_text("{}")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_existing_out_dir_keeps_other_files(tmp_path):
    out = tmp_path / "result"
    out.mkdir()
    (out / "keep.txt").write_text("old")
    (out / "fit.json").write_text("old fit")
    with StagedOutput(out) as stage:
        stage.path("fit.json").write_text("new fit")
        stage.path("more/new.txt").write_text("new")
    assert (out / "keep.txt").read_text() == "old"
    assert (out / "fit.json").read_text() == "new fit"
    assert (out / "more" / "new.txt").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result"]


def test_existing_out_dir_untouched_on_exception(tmp_path):
    out = tmp_path / "result"
    out.mkdir()
    (out / "fit.json").write_text("old fit")
    before = listing(out)
    with pytest.raises(Boom):
        with StagedOutput(out) as stage:
            stage.path("fit.json").write_text("new fit")
            stage.path("extra.txt").write_text("x")
            raise Boom()
    assert listing(out) == before
    assert (out / "fit.json").read_text() == "old fit"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result"]


def test_out_dir_is_a_file(tmp_path):
    out = tmp_path / "result"
    out.write_text("I am a file")
    with pytest.raises(InputError) as ei:
        with StagedOutput(out):
            pass  # pragma: no cover
    msg = str(ei.value)
    assert str(out) in msg and "output folder" in msg and "a directory" in msg
    assert out.read_text() == "I am a file"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result"]


def test_out_dir_parent_is_a_file(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="a directory"):
        with StagedOutput(tmp_path / "f" / "result"):
            pass  # pragma: no cover


def test_unwritable_parent_chmod(tmp_path):
    parent = tmp_path / "locked"
    parent.mkdir()
    parent.chmod(0o500)
    try:
        if os.access(parent, os.W_OK):
            pytest.skip("running with privileges that ignore directory permissions (root)")
        with pytest.raises(InputError, match="not writable") as ei:
            with StagedOutput(parent / "result"):
                pass  # pragma: no cover
        assert str(parent / "result") in str(ei.value)
        assert list(parent.iterdir()) == []
    finally:
        parent.chmod(0o700)


def test_unwritable_parent_simulated(tmp_path, monkeypatch):
    """The same path as the chmod test, for runs as root (where chmod 0o500 does not bite)."""
    real_mkdir = os.mkdir

    def deny(path, *args, **kwargs):
        if os.path.basename(os.fspath(path)).startswith(TEMP_PREFIX):
            raise PermissionError(13, "Permission denied", os.fspath(path))
        return real_mkdir(path, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", deny)
    out = tmp_path / "new" / "result"
    with pytest.raises(InputError, match="not writable") as ei:
        with StagedOutput(out):
            pass  # pragma: no cover
    assert ei.value.field == "output folder"
    assert list(tmp_path.iterdir()) == []  # the created parent "new" was removed again


def test_a_permission_fault_on_the_outputs_own_files_names_the_output_file(tmp_path, monkeypatch):
    """An existing output folder this user may not write (chmod 555, or chattr +i even for root):
    the move of a staged file fails with EPERM/EACCES; the user gets the output's own path, not the
    staging one, and nothing is left. The same fault on another path (an input) stays what it is."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "fit.json").write_text("{}")  # an earlier output
    real_replace = os.replace

    def deny(src, dst, *args, **kwargs):
        if os.fspath(dst).startswith(os.fspath(out)) and TEMP_PREFIX + "commit" not in os.fspath(src):  # not the roll-back's
            raise PermissionError(1, "Operation not permitted", os.fspath(src))
        return real_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", deny)
    with pytest.raises(OutputError) as ei:
        with StagedOutput(out, replace=True) as stage:
            stage.path("fit.json").write_text('{"new": 1}')
    assert str(ei.value) == f"{out / 'fit.json'}: output file: expected to be able to write it, found the operation not permitted " \
                            "(an immutable or protected file or folder)"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"] and (out / "fit.json").read_text() == "{}"
    elsewhere = tmp_path / "weights.safetensors"
    with pytest.raises(PermissionError):
        with StagedOutput(tmp_path / "other"):
            raise PermissionError(13, "Permission denied", str(elsewhere))


def test_stage_path_rejects_escapes(tmp_path):
    with StagedOutput(tmp_path / "out") as stage:
        for bad in ["../x", "/abs/x", "a/../../x", ""]:
            with pytest.raises(ValueError):
                stage.path(bad)
    with pytest.raises(RuntimeError):
        stage.path("late.txt")


def test_empty_stage_creates_empty_dir(tmp_path):
    with StagedOutput(tmp_path / "out"):
        pass
    assert (tmp_path / "out").is_dir() and listing(tmp_path / "out") == []


def test_symlinked_out_dir(tmp_path):
    real = tmp_path / "real"
    real.mkdir()
    link = tmp_path / "link"
    link.symlink_to(real, target_is_directory=True)
    with StagedOutput(link) as stage:
        stage.path("a.txt").write_text("a")
    assert (real / "a.txt").read_text() == "a"
    assert link.is_symlink()


# ---------------------------------------------------------------------------------------------
# atomic single-file writes
# ---------------------------------------------------------------------------------------------


def test_atomic_write_bytes_and_text(tmp_path):
    p = tmp_path / "f.bin"
    assert atomic_write_bytes(p, b"\x00\x01") == p
    assert p.read_bytes() == b"\x00\x01"
    atomic_write_text(p, "héllo\n")
    assert p.read_bytes() == "héllo\n".encode()
    assert [q.name for q in tmp_path.iterdir()] == ["f.bin"]


def test_atomic_write_keeps_mode(tmp_path):
    p = tmp_path / "secret.txt"
    p.write_text("old")
    p.chmod(0o600)
    atomic_write_text(p, "new")
    assert stat.S_IMODE(p.stat().st_mode) == 0o600
    assert p.read_text() == "new"


def test_atomic_write_failure_leaves_old_file(tmp_path, monkeypatch):
    p = tmp_path / "f.txt"
    p.write_text("old")

    def fail(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", fail)
    with pytest.raises(OutputError, match="no space left"):  # a full disk is one facegeo error
        atomic_write_text(p, "new")
    assert p.read_text() == "old"
    assert [q.name for q in tmp_path.iterdir()] == ["f.txt"]


def test_atomic_write_errors(tmp_path):
    with pytest.raises(InputError, match="a directory"):
        atomic_write_bytes(tmp_path, b"x")
    with pytest.raises(InputError, match="existing folder"):
        atomic_write_bytes(tmp_path / "missing" / "f.txt", b"x")


def test_atomic_write_unwritable_simulated(tmp_path, monkeypatch):
    real_open = os.open

    def deny(path, flags, *args, **kwargs):
        if os.path.basename(os.fspath(path)).startswith(TEMP_PREFIX):
            raise PermissionError(13, "Permission denied", os.fspath(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", deny)
    with pytest.raises(InputError, match="permission denied"):
        atomic_write_text(tmp_path / "f.txt", "x")
    assert list(tmp_path.iterdir()) == []


def test_stale_temporaries_of_this_host_only(tmp_path):
    """A dead process's staging folder is removed; one named by another host (a batch worker
    writing to a shared file system) is not, since its process cannot be checked from here."""
    import subprocess
    import sys

    from facegeo.staged_output import _host, remove_stale_temporaries

    import hashlib
    import socket

    host = _host()
    assert host == hashlib.sha1(socket.gethostname().encode()).hexdigest()[:8]  # the name socket gives, without it
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    mine = tmp_path / f"{TEMP_PREFIX}{pid}-h{host}-0000abcd"
    other = tmp_path / f"{TEMP_PREFIX}{pid}-h{'0' * 8 if host != '0' * 8 else '1' * 8}-0000abcd"
    old_style = tmp_path / f"{TEMP_PREFIX}{pid}-0000abcd"
    for d in (mine, other, old_style):
        d.mkdir()
    assert sorted(remove_stale_temporaries(tmp_path)) == sorted([mine, old_style])
    assert other.is_dir()
    with StagedOutput(tmp_path / "out") as stage:
        assert stage.staging_dir.name.startswith(f"{TEMP_PREFIX}{os.getpid()}-h{host}-")


def test_other_temporaries_are_removed_and_this_processs_kept(tmp_path):
    """What a batch removes once none of its jobs runs: every temporary but its own process's,
    of any host or process, live or not; files that are not temporaries stay."""
    from facegeo.staged_output import _host, remove_other_temporaries

    host = _host()

    own = tmp_path / f"{TEMP_PREFIX}{os.getpid()}-h{host}-0000abcd"
    others = [tmp_path / f"{TEMP_PREFIX}1-h{host}-0000abcd", tmp_path / f"{TEMP_PREFIX}1-h{'0' * 8}-0000abcd",
              tmp_path / f"{TEMP_PREFIX}x-file"]
    keep = tmp_path / "photo-1"
    for d in (own, others[0], others[1], keep):
        d.mkdir()
    others[2].write_text("half")
    assert sorted(remove_other_temporaries(tmp_path)) == sorted(others)
    assert own.is_dir() and keep.is_dir()


def test_a_scratch_folder_is_removed_and_a_left_one_is_never_committed(tmp_path):
    """The usdz package is built in a scratch folder beside its target (inside the staging folder
    during a reconstruction): removed on exit; one left by a writer killed outright (here: made
    by hand) is not moved into the output, and the next run removes it once its process is gone."""
    from facegeo.staged_output import scratch_folder

    with scratch_folder(tmp_path) as scratch:
        (scratch / "face.usdc").write_bytes(b"x")
        assert scratch.parent == tmp_path and scratch.name.startswith(TEMP_PREFIX)
    assert list(tmp_path.iterdir()) == []
    out = tmp_path / "out"
    with StagedOutput(out) as stage:
        stage.path("face.usdz").write_bytes(b"usdz")
        left = stage.staging_dir / f"{TEMP_PREFIX}999999999-h00000000-deadbeef"
        left.mkdir()
        (left / "face.usdc").write_bytes(b"half")
    assert listing(out) == ["face.usdz"]
