"""Safe output files: every file the library writes goes through this module.

A file is written to a temporary file in the directory of its final target
and moved into place with :func:`os.replace`, so a reader never sees a partly
written file and an error (including a ``KeyboardInterrupt``) never leaves a
half-written, truncated or clobbered file behind: the temporary file is
removed and the old file, if any, is untouched.

Policy
------
Special files
    A target that exists and is not a regular file (a directory, a character
    or block device such as ``/dev/full`` or ``/dev/null``, a FIFO, a socket)
    is **refused** with :class:`OutputFileError` (one line); nothing is
    written and the target is untouched.  (A plain ``os.replace`` would
    silently swap a device node for a regular file when run as root.)
Symbolic links
    A symlink is **written through deliberately**: the link is resolved
    (all levels, :func:`os.path.realpath`) and its final target is replaced
    atomically in the target's own directory; the link itself is kept and
    still points to the new content.  The final target is subject to the
    same policy (refused if it is a special file).  A dangling link creates
    its target (whose directory must exist).  A symlink loop is refused.
Permissions
    An existing file keeps its permission bits (and, where the process may
    set them, its owner and group).  A file the process may not write
    (:func:`os.access`, e.g. mode ``0o444`` for its owner) is refused, as
    :func:`open` would refuse it, although the directory would allow the
    rename.  A new file gets the mode :func:`open`
    would give it, ``0o666 & ~umask`` (``0o644`` with the usual umask 022):
    the umask is respected.
Missing directories
    By default a missing parent directory is **refused**
    (:class:`OutputFileError`, "directory ... does not exist").  With
    ``create_dirs=True`` the missing directories are created (mode
    ``0o777 & ~umask``) and **reported**: :attr:`OutputTarget.created_dirs`
    of the returned object lists them (outermost first), so a caller such as
    the command line can print "created directory ...".

Use :func:`check_output_path` to validate a target before a long
computation (it writes nothing), :func:`write_text_atomic` /
:func:`write_bytes_atomic` for data in memory, and :func:`atomic_output`
for writers that want a file name (e.g. ``Figure.savefig``).
"""
from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Optional, Tuple

__all__ = [
    "OutputFileError",
    "OutputTarget",
    "check_output_path",
    "write_text_atomic",
    "read_json_object",
    "write_bytes_atomic",
    "atomic_output",
]

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISSOCK, "a socket"),
)


class OutputFileError(ValueError):
    """An output path the library refuses to write (one-line message).

    Raised for a target that is a directory, a device, a FIFO or a socket, a
    read-only file, a missing directory (unless ``create_dirs=True``), a symlink loop, or an
    unwritable directory.  Subclass of :class:`ValueError`.
    """


@dataclass(frozen=True)
class OutputTarget:
    """Where an output file goes (result of :func:`check_output_path` and the writers).

    Attributes
    ----------
    path : pathlib.Path
        The path as given.
    target : pathlib.Path
        The file actually replaced: ``path`` itself, or the final target of
        a symlink (write-through).
    exists : bool
        True if ``target`` exists (and is a regular file) before writing.
    created_dirs : tuple of pathlib.Path
        Directories that were created (writers) or would be created
        (:func:`check_output_path`) with ``create_dirs=True``, outermost
        first; empty if none.
    """

    path: Path
    target: Path
    exists: bool
    created_dirs: Tuple[Path, ...] = field(default_factory=tuple)

    @property
    def via_symlink(self) -> bool:
        """True if ``path`` is a symlink written through to ``target``."""
        return self.target != self.path


def _kind(mode: int) -> Optional[str]:
    for test, name in _KINDS:
        if test(mode):
            return name
    return None if stat.S_ISREG(mode) else "not a regular file"


def _plan(path, create_dirs: bool) -> Tuple[OutputTarget, Optional[os.stat_result]]:
    """Apply the policy to ``path`` without writing: (target info, stat of the target)."""
    try:
        given = Path(os.fspath(path))
    except TypeError:
        raise OutputFileError(f"output path must be a str or a path, got {type(path).__name__}") \
            from None
    if str(given) in ("", "."):
        raise OutputFileError("empty output path")
    target = given
    try:
        st = os.lstat(given)
    except FileNotFoundError:
        st = None
    except OSError as e:  # ENOTDIR (a parent is a file), EACCES, ...
        raise OutputFileError(f"cannot write {given}: {e.strerror or e}") from None
    if st is not None and stat.S_ISLNK(st.st_mode):
        target = Path(os.path.realpath(given))
        try:
            st = os.lstat(target)
        except FileNotFoundError:
            st = None  # dangling link: its target is created
        except OSError as e:
            raise OutputFileError(f"cannot write {given} (symlink to {target}): "
                                  f"{e.strerror or e}") from None
        if st is not None and stat.S_ISLNK(st.st_mode):
            raise OutputFileError(f"{given} is a symlink that cannot be resolved (a loop?)")
    if st is not None:
        kind = _kind(st.st_mode)
        via = f" (symlink to {target})" if target != given else ""
        if kind is not None:
            raise OutputFileError(f"{given}{via} is {kind}, not a regular file: "
                                  "refusing to replace it")
        if not os.access(target, os.W_OK):
            raise OutputFileError(f"{given}{via} is read-only (mode "
                                  f"{stat.S_IMODE(st.st_mode):04o}): refusing to replace it")
    # the directory of the final target
    parent = target.parent
    missing = []
    d = parent
    while True:
        try:
            dst = os.stat(d)
        except FileNotFoundError:
            missing.append(d)
            if d.parent == d:
                break
            d = d.parent
            continue
        except OSError as e:
            raise OutputFileError(f"cannot write {given}: {d}: {e.strerror or e}") from None
        if not stat.S_ISDIR(dst.st_mode):
            raise OutputFileError(f"cannot write {given}: {d} is not a directory")
        if not missing and not os.access(d, os.W_OK | os.X_OK):
            raise OutputFileError(f"cannot write {given}: directory {d} is not writable")
        if missing and not os.access(d, os.W_OK | os.X_OK):
            raise OutputFileError(f"cannot create directory {missing[-1]}: "
                                  f"{d} is not writable")
        break
    if missing and not create_dirs:
        raise OutputFileError(f"cannot write {given}: directory {parent} does not exist")
    return OutputTarget(given, target, st is not None, tuple(reversed(missing))), st


def check_output_path(path, *, create_dirs: bool = False) -> OutputTarget:
    """Check that ``path`` may be written under the module's policy; write nothing.

    Call it before a long computation so that a bad target fails at once.

    Parameters
    ----------
    path : str or os.PathLike
        The output file.
    create_dirs : bool
        Accept a missing parent directory (it would be created by the writer).

    Returns
    -------
    OutputTarget
        ``target`` is the file that would be replaced (the symlink's final
        target for a symlink); ``created_dirs`` the directories that would be
        created.

    Raises
    ------
    OutputFileError
        If the target is not a regular file (directory, device, FIFO,
        socket) or is read-only, a symlink loop, or its directory is missing
        (and ``create_dirs`` is False), not a directory or not writable.
        Writability is probed: a temporary file (or, for a missing directory,
        a temporary directory) is created in the nearest existing directory
        and removed at once, so a file system that the permission bits do not
        describe (``/proc``, a read-only mount) fails here, not after the work.
    """
    info = _plan(path, create_dirs)[0]
    base = info.created_dirs[0].parent if info.created_dirs else info.target.parent
    try:
        if info.created_dirs:
            probe = Path(tempfile.mkdtemp(prefix=".probe-", dir=base))
            probe.rmdir()
        else:
            fd, probe = _open_temp(base, info.target.name)
            os.close(fd)
            os.unlink(probe)
    except OSError as e:
        what = (f"cannot create directory {info.created_dirs[0]}" if info.created_dirs
                else f"cannot write {info.path}")
        raise OutputFileError(f"{what}: {e.strerror or e}") from None
    return info


def _open_temp(directory: Path, name: str) -> Tuple[int, Path]:
    """Create an empty temp file next to the target; mode 0o666 & ~umask (as open())."""
    for _ in range(100):
        tmp = directory / f".{name}.{secrets.token_hex(4)}.tmp"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0),
                         0o666)
        except FileExistsError:
            continue
        return fd, tmp
    raise FileExistsError(errno.EEXIST, "no free temporary file name", str(directory))


def _make_dirs(dirs) -> None:
    for d in dirs:
        try:
            os.mkdir(d)
        except FileExistsError:
            if not d.is_dir():
                raise OutputFileError(f"cannot create directory {d}: a file is in the way") \
                    from None


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_output(path, *, create_dirs: bool = False) -> Iterator[Path]:
    """Context manager: write a file by name, then move it into place atomically.

    Yields the path of an empty temporary file in the target's directory;
    the body writes the complete content to it (by name, e.g.
    ``fig.savefig(tmp, format="png")``: give the format explicitly, the
    temporary name ends in ``.tmp``).  On a normal exit the file gets the
    permission bits of the policy and replaces the target with
    :func:`os.replace`; on any exception (also ``KeyboardInterrupt``) it is
    removed and the target is untouched.

    Parameters
    ----------
    path : str or os.PathLike
        The output file (a symlink is written through, see the module
        docstring).
    create_dirs : bool
        Create a missing parent directory (reported by
        :attr:`OutputTarget.created_dirs`, see :func:`write_text_atomic`).

    Yields
    ------
    pathlib.Path
        The temporary file to write.

    Raises
    ------
    OutputFileError
        If the target is refused by the policy (nothing is written), or
        writing or renaming fails (the temporary file is removed; the message
        names the target).
    """
    with _atomic(path, create_dirs) as (tmp, _info):
        yield tmp


@contextlib.contextmanager
def _atomic(path, create_dirs):
    info, st = _plan(path, create_dirs)
    _make_dirs(info.created_dirs)
    target = info.target
    try:
        fd, tmp = _open_temp(target.parent, target.name)
    except OSError as e:
        raise OutputFileError(f"cannot write {info.path}: {e.strerror or e}") from None
    try:
        os.close(fd)
        yield tmp, info
        with open(tmp, "rb") as fh:  # flush to disk before the rename
            os.fsync(fh.fileno())
        if st is not None:  # keep the permission bits (and owner/group if allowed)
            if hasattr(os, "chown") and (st.st_uid, st.st_gid) != _owner(tmp):
                try:
                    os.chown(tmp, st.st_uid, st.st_gid)
                except OSError:
                    pass
            os.chmod(tmp, stat.S_IMODE(st.st_mode))
        os.replace(tmp, target)
    except OSError as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        # name the file the user asked for (a full disk names only a temporary one, or none)
        raise OutputFileError(f"cannot write {info.path}: {e.strerror or e} "
                              "(the previous file, if any, is unchanged)") from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    _fsync_dir(target.parent)


def _owner(p: Path) -> Tuple[int, int]:
    s = os.stat(p)
    return s.st_uid, s.st_gid


def write_bytes_atomic(path, data: bytes, *, create_dirs: bool = False) -> OutputTarget:
    """Write ``data`` to ``path`` atomically under the module's policy.

    Parameters
    ----------
    path : str or os.PathLike
        The output file.
    data : bytes
        The complete content.
    create_dirs : bool
        Create a missing parent directory (reported in the result).

    Returns
    -------
    OutputTarget
        ``target``: the file replaced; ``created_dirs``: directories created.

    Raises
    ------
    OutputFileError
        If the target is refused by the policy (nothing is written).
    OSError
        If writing fails (no partial file is left; the target is untouched).
    """
    with _atomic(path, create_dirs) as (tmp, info):
        with open(tmp, "wb") as fh:
            fh.write(data)
    return info


def read_json_object(path, what):
    """Read a JSON file that must hold an object; one-line errors naming the file.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    what : str
        What the file is, for the messages (e.g. ``"result file"``).

    Returns
    -------
    dict

    Raises
    ------
    ValueError
        ``"{path}: {what} not found"``, ``"... is a directory"``, ``"cannot
        read ..."``, ``"invalid JSON at line L column C: ..."`` or ``"{what}
        must hold a JSON object"``.
    """
    import json

    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ValueError(f"{p}: {what} not found") from None
    except IsADirectoryError:
        raise ValueError(f"{p}: {what} is a directory") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{p}: cannot read {what} ({' '.join(str(e).split())})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f"{p}: invalid JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
    except RecursionError:
        raise ValueError(f"{p}: {what} is nested too deeply to be read (JSON nesting beyond "
                         f"Python's recursion limit)") from None
    if not isinstance(data, dict):
        raise ValueError(f"{p}: {what} must hold a JSON object")
    return data


def write_text_atomic(path, text: str, *, encoding: str = "utf-8", newline: str = "",
                      create_dirs: bool = False) -> OutputTarget:
    """Write ``text`` to ``path`` atomically under the module's policy.

    The text is written to a temporary file in the target's directory and
    moved into place with :func:`os.replace`; on any error (including
    ``KeyboardInterrupt``) the temporary file is removed and the target is
    untouched.  See the module docstring for special files, symlinks,
    permissions and missing directories.

    Parameters
    ----------
    path : str or os.PathLike
        The output file.
    text : str
        The complete content.
    encoding : str
        Text encoding (default UTF-8).
    newline : str
        As :func:`open`'s ``newline``; the default ``""`` writes ``"\\n"``
        unchanged on every platform.
    create_dirs : bool
        Create a missing parent directory instead of refusing; the created
        directories are listed in the result's ``created_dirs``.

    Returns
    -------
    OutputTarget
        ``target``: the file replaced (a symlink's final target);
        ``created_dirs``: the directories created (outermost first).

    Raises
    ------
    OutputFileError
        If the target is a directory, device, FIFO or socket, read-only, a
        symlink loop, or its directory is missing (without ``create_dirs``)
        or not writable; nothing is written.
    OSError
        If writing fails (e.g. disk full); no partial file is left.
    """
    if not isinstance(text, str):
        raise TypeError(f"text must be a str, got {type(text).__name__}")
    with _atomic(path, create_dirs) as (tmp, info):
        with open(tmp, "w", encoding=encoding, newline=newline) as fh:
            fh.write(text)
    return info
