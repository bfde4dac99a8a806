"""Tests of :mod:`plant.logs.fileio`: the output-file policy (issue 11, part 4).

Special files are refused and untouched, symlinks are written through (the
link is kept, its target replaced), permission bits are kept, a missing
directory is refused by default and created (and reported) on request, and no
temporary file is ever left behind.
"""
from __future__ import annotations

import json
import os
import stat
import threading
from pathlib import Path

import numpy as np
import pytest

from plant.logs.fileio import (
    OutputFileError,
    atomic_output,
    check_output_path,
    write_bytes_atomic,
    write_text_atomic,
)


def listing(d):
    return sorted(p.name for p in Path(d).iterdir())


def mode_of(p):
    return stat.S_IMODE(os.stat(p).st_mode)


# ------------------------------------------------------------------- basic writes
def test_new_file_written_with_umask_mode(tmp_path):
    old = os.umask(0o027)
    try:
        info = write_text_atomic(tmp_path / "a.txt", "hello\n")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").read_text() == "hello\n"
    assert mode_of(tmp_path / "a.txt") == 0o666 & ~0o027
    assert info.target == tmp_path / "a.txt" and not info.exists and not info.created_dirs
    assert listing(tmp_path) == ["a.txt"]


def test_newlines_written_unchanged(tmp_path):
    write_text_atomic(tmp_path / "a.csv", "a,b\r\n1,2\n")
    assert (tmp_path / "a.csv").read_bytes() == b"a,b\r\n1,2\n"


def test_overwrite_keeps_mode_0600(tmp_path):
    p = tmp_path / "secret.json"
    p.write_text("old")
    os.chmod(p, 0o600)
    info = write_text_atomic(p, "new")
    assert p.read_text() == "new" and info.exists
    assert mode_of(p) == 0o600
    os.chmod(p, 0o640)
    write_bytes_atomic(p, b"newer")
    assert p.read_bytes() == b"newer" and mode_of(p) == 0o640
    assert listing(tmp_path) == ["secret.json"]


def test_read_only_file_replaced_only_if_writable(tmp_path):
    """Mode 0444: root may write it (mode kept), anyone else is refused (file untouched)."""
    p = tmp_path / "ro.txt"
    p.write_text("old")
    os.chmod(p, 0o444)
    if os.access(p, os.W_OK):  # root: open(p, "w") would succeed too
        write_text_atomic(p, "new")
        assert p.read_text() == "new" and mode_of(p) == 0o444
    else:
        with pytest.raises(OutputFileError, match="read-only"):
            write_text_atomic(p, "new")
        assert p.read_text() == "old"
    assert listing(tmp_path) == ["ro.txt"]


def test_read_only_file_refused_for_a_non_root_user(tmp_path, monkeypatch):
    """The same check as a user who cannot write the file (os.access mocked)."""
    p = tmp_path / "ro.txt"
    p.write_text("old")
    os.chmod(p, 0o444)
    real_access = os.access

    def access(path, mode, *a, **kw):
        if Path(path) == p and mode & os.W_OK:
            return False
        return real_access(path, mode, *a, **kw)

    monkeypatch.setattr(os, "access", access)
    with pytest.raises(OutputFileError, match=r"read-only \(mode 0444\)"):
        write_text_atomic(p, "new")
    monkeypatch.undo()
    assert p.read_text() == "old" and listing(tmp_path) == ["ro.txt"]


# ------------------------------------------------------------------ special files
def test_fifo_refused_and_untouched(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for fn in (lambda: write_text_atomic(fifo, "x"), lambda: check_output_path(fifo)):
        with pytest.raises(OutputFileError) as exc:
            fn()
        msg = str(exc.value)
        assert "FIFO" in msg and str(fifo) in msg and "\n" not in msg
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert listing(tmp_path) == ["pipe"]


def test_device_refused(tmp_path):
    before = os.stat("/dev/null")
    with pytest.raises(OutputFileError, match="character device"):
        write_text_atomic("/dev/null", "x")
    after = os.stat("/dev/null")
    assert stat.S_ISCHR(after.st_mode) and after.st_ino == before.st_ino
    assert not [n for n in os.listdir("/dev") if n.startswith(".null.")]


def test_directory_refused(tmp_path):
    d = tmp_path / "out"
    d.mkdir()
    (d / "keep").write_text("k")
    with pytest.raises(OutputFileError, match="is a directory"):
        write_text_atomic(d, "x")
    with pytest.raises(OutputFileError, match="is a directory"):
        check_output_path(d)
    assert listing(d) == ["keep"] and listing(tmp_path) == ["out"]


def test_socket_refused(tmp_path):
    import socket

    path = tmp_path / "s"
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        s.bind(str(path))
        with pytest.raises(OutputFileError, match="socket"):
            write_text_atomic(path, "x")
        assert stat.S_ISSOCK(os.lstat(path).st_mode)
    finally:
        s.close()


# ---------------------------------------------------------------------- symlinks
def test_symlink_written_through_and_kept(tmp_path):
    real_dir = tmp_path / "real"
    real_dir.mkdir()
    target = real_dir / "result.json"
    target.write_text("old")
    os.chmod(target, 0o600)
    link = tmp_path / "link.json"
    link.symlink_to(Path("real") / "result.json")  # relative link
    info = write_text_atomic(link, "new")
    assert link.is_symlink() and os.readlink(link) == str(Path("real") / "result.json")
    assert target.read_text() == "new" and link.read_text() == "new"
    assert mode_of(target) == 0o600
    assert info.via_symlink and info.target == target.resolve()
    assert listing(tmp_path) == ["link.json", "real"] and listing(real_dir) == ["result.json"]


def test_chain_of_symlinks_and_dangling_link(tmp_path):
    target = tmp_path / "t.txt"
    (tmp_path / "l1").symlink_to(target)
    (tmp_path / "l2").symlink_to(tmp_path / "l1")
    write_text_atomic(tmp_path / "l2", "created")  # dangling: its target is created
    assert target.read_text() == "created"
    assert (tmp_path / "l2").is_symlink() and (tmp_path / "l1").is_symlink()


def test_symlink_to_special_file_refused(tmp_path):
    link = tmp_path / "null.json"
    link.symlink_to("/dev/null")
    with pytest.raises(OutputFileError, match=r"symlink to /dev/null.*character device"):
        write_text_atomic(link, "x")
    assert link.is_symlink() and os.readlink(link) == "/dev/null"
    d = tmp_path / "d"
    d.mkdir()
    (tmp_path / "dlink").symlink_to(d)
    with pytest.raises(OutputFileError, match="directory"):
        check_output_path(tmp_path / "dlink")


def test_symlink_loop_refused(tmp_path):
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    with pytest.raises(OutputFileError, match="loop"):
        write_text_atomic(tmp_path / "a", "x")
    assert listing(tmp_path) == ["a", "b"]


# ----------------------------------------------------------- missing directories
def test_missing_directory_refused_by_default(tmp_path):
    p = tmp_path / "no" / "such" / "out.json"
    with pytest.raises(OutputFileError, match="does not exist"):
        write_text_atomic(p, "x")
    with pytest.raises(OutputFileError, match="does not exist"):
        check_output_path(p)
    assert listing(tmp_path) == []


def test_missing_directory_created_and_reported(tmp_path):
    p = tmp_path / "no" / "such" / "out.json"
    planned = check_output_path(p, create_dirs=True)
    assert planned.created_dirs == (tmp_path / "no", tmp_path / "no" / "such")
    assert listing(tmp_path) == []  # the check writes nothing
    info = write_text_atomic(p, "x", create_dirs=True)
    assert p.read_text() == "x"
    assert info.created_dirs == planned.created_dirs
    assert write_text_atomic(p, "y", create_dirs=True).created_dirs == ()


def test_parent_is_a_file_refused(tmp_path):
    f = tmp_path / "file"
    f.write_text("keep")
    for create in (False, True):
        with pytest.raises(OutputFileError, match="not a directory|Not a directory"):
            write_text_atomic(f / "out.json", "x", create_dirs=create)
    assert f.read_text() == "keep"


# ------------------------------------------------------------ failures: no debris
def test_unencodable_text_leaves_old_file_and_no_temp(tmp_path):
    p = tmp_path / "out.txt"
    p.write_text("old")
    with pytest.raises(UnicodeEncodeError):
        write_text_atomic(p, "caf\u00e9", encoding="ascii")
    assert p.read_text() == "old" and listing(tmp_path) == ["out.txt"]


def test_json_value_error_leaves_no_file(tmp_path):
    from identification.result import write_json_atomic

    p = tmp_path / "out.json"
    with pytest.raises(TypeError):
        write_json_atomic(p, {"a": object()})
    with pytest.raises(ValueError):
        write_json_atomic(p, {"a": float("nan")})
    assert listing(tmp_path) == []
    p.write_text("old")
    with pytest.raises(TypeError):
        write_json_atomic(p, {"a": np.float32})
    assert p.read_text() == "old" and listing(tmp_path) == ["out.json"]


@pytest.mark.parametrize("exc", [KeyboardInterrupt, RuntimeError])
def test_exception_inside_atomic_output_removes_temp(tmp_path, exc):
    p = tmp_path / "plot.png"
    p.write_bytes(b"old")
    with pytest.raises(exc):
        with atomic_output(p) as tmp:
            assert tmp.parent == tmp_path and tmp.exists()
            tmp.write_bytes(b"partial")
            raise exc
    assert p.read_bytes() == b"old" and listing(tmp_path) == ["plot.png"]


def test_atomic_output_by_name(tmp_path):
    p = tmp_path / "x.bin"
    with atomic_output(p) as tmp:
        tmp.write_bytes(b"\x00\x01")
        assert not p.exists()  # readers never see a partial file
    assert p.read_bytes() == b"\x00\x01" and listing(tmp_path) == ["x.bin"]


def test_concurrent_writers_never_expose_partial_content(tmp_path):
    p = tmp_path / "c.json"
    texts = [json.dumps({"i": i, "pad": "x" * 50_000}) for i in range(4)]
    threads = [threading.Thread(target=write_text_atomic, args=(p, t)) for t in texts]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert p.read_text() in texts and listing(tmp_path) == ["c.json"]


def test_bad_path_type():
    with pytest.raises(OutputFileError, match="path"):
        write_text_atomic(3.5, "x")
    with pytest.raises(OutputFileError, match="empty"):
        check_output_path("")
