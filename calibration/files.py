"""Atomic output files: a crash, a full disk or a failed serialisation never leaves a half-written file.

Every file cellcal writes (models, recordings, plans, reports, pages, JSON summaries) goes through
:func:`atomic_open` (or its shorthands :func:`atomic_write_text` and :func:`atomic_write_bytes`):

- the content goes to a temporary file in the same folder, is fsynced, then renamed over the target, so a
  reader sees the old file or the new one, never a mix;
- a new file gets the mode a plain ``open(path, "w")`` would give (0o666 minus the umask); an existing file
  keeps its mode (and, where the process may, its owner);
- a symlink, a folder, a device node, a FIFO or a socket at the target is refused, never replaced (so
  ``--json /dev/full`` does not turn the device into a regular file); an empty path or one under a file is
  refused too. :func:`check_output_path` runs the same checks early, before any work is done.

One process at a time: :class:`ExclusiveLock` is an exclusive ``flock`` on a lock file with its holder written in
it, released on :meth:`~ExclusiveLock.release` or by the kernel when the process ends (even by a crash, so no lock is
ever stale): a session folder's collector and a MotoROS controller's driver hold one.

Every input file (recordings, model files, cell files, plan files, path files, jobs) is read through
:func:`read_input_bytes` (or :func:`read_input_text`): only a regular file is read (a FIFO, a device such as
``/dev/zero`` or a socket is refused before anything is read: opened without blocking, checked, then read), and
never more than its bound of bytes (``MAX_INPUT_BYTES`` unless the reader gives its own), so a huge or endless
input is refused instead of filling memory or hanging.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import secrets
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from calibration.errors import OutputError

_KINDS = {stat.S_IFDIR: "a folder", stat.S_IFCHR: "a character device", stat.S_IFBLK: "a block device",
          stat.S_IFIFO: "a FIFO", stat.S_IFSOCK: "a socket"}


def check_output_path(path: str | Path) -> os.stat_result | None:
    """Refuse an output path that must not be replaced; the existing file's status, None when it is new.

    Raises:
        OutputError: the path is empty, a symlink, a folder, a device, a FIFO or a socket, or lies under a file.
    """
    if not str(path):
        raise OutputError(path, "empty output path; give a file name")
    path = Path(path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        raise OutputError(path, "lies under a file, not a folder") from None
    if st is None:
        for parent in path.parents:
            if parent.exists() or parent.is_symlink():
                if not parent.is_dir():
                    raise OutputError(path, f"lies under {parent}, which is not a folder")
                break
        return None
    if stat.S_ISLNK(st.st_mode):
        raise OutputError(path, "is a symbolic link; refusing to replace it (give the file it points to)")
    if not stat.S_ISREG(st.st_mode):
        kind = _KINDS.get(stat.S_IFMT(st.st_mode), "not a regular file")
        hint = "give a file name inside it" if stat.S_ISDIR(st.st_mode) else "leave the option out to write nothing"
        raise OutputError(path, f"is {kind}; refusing to replace it with a regular file ({hint})")
    return st


def _create_temp(path: Path) -> tuple[int, Path]:
    while True:
        tmp = path.parent / f".{path.name}.{secrets.token_hex(6)}.tmp"
        try:  # mode 0o666: the kernel applies the umask, exactly as for open(path, "w")
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666), tmp
        except FileExistsError:
            continue


def _keep_owner_and_mode(fd: int, st: os.stat_result | None) -> None:
    if st is None:
        return
    os.fchmod(fd, stat.S_IMODE(st.st_mode))
    if hasattr(os, "fchown") and (st.st_uid, st.st_gid) != (os.geteuid(), os.getegid()):
        with contextlib.suppress(PermissionError):
            os.fchown(fd, st.st_uid, st.st_gid)


def _fsync_folder(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_open(path: str | Path, binary: bool = False) -> Iterator[IO[Any]]:
    """A file object whose content replaces ``path`` only when the ``with`` block ends without an exception.

    Text mode writes UTF-8 with no newline translation. On any exception (a failed serialisation midway, a
    full disk) the temporary file is removed, ``path`` is left as it was and the exception propagates
    (an ``OSError`` as :class:`OutputError`).

    Raises:
        OutputError: the path is refused (see :func:`check_output_path`) or the write failed.
    """
    st = check_output_path(path)  # before Path(): Path("") is the current folder
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = _create_temp(path)
    except OSError as e:
        raise OutputError(path, f"cannot write ({e.strerror or e})") from e
    try:
        with (os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8", newline="")) as f:
            _keep_owner_and_mode(f.fileno(), st)
            yield f
            f.flush()
            os.fsync(f.fileno())
        check_output_path(path)  # not swapped for a symlink or a device while we wrote
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if isinstance(e, OSError):
            raise OutputError(path, f"cannot write ({e.strerror or e})") from e
        raise
    _fsync_folder(path.parent)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically; see :func:`atomic_open`."""
    with atomic_open(path) as f:
        f.write(text)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically; see :func:`atomic_open`."""
    with atomic_open(path, binary=True) as f:
        f.write(data)


#: Largest input file read by default [bytes]: 64 MiB, far beyond any model, cell, plan, path or job file; a reader
#: whose files may be larger (recordings) passes its own bound.
MAX_INPUT_BYTES = 64 * 2**20


class InputRefused(OSError):
    """An input path that is not read: not a regular file, or larger than its bound. An ``OSError`` (``strerror``
    says why), so a reader's ``except OSError`` turns it into its own one-line error naming the file."""

    def __init__(self, path: str | Path, reason: str) -> None:
        super().__init__(errno.EINVAL, reason, str(path))


def _check_input(path: str | Path, st: os.stat_result, max_bytes: int) -> None:
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(errno.EISDIR, "is a folder", str(path))
    if not stat.S_ISREG(st.st_mode):
        kind = _KINDS.get(stat.S_IFMT(st.st_mode), "not a regular file")
        raise InputRefused(path, f"is {kind}, not a regular file; only regular files are read")
    if st.st_size > max_bytes:
        raise InputRefused(path, f"is {st.st_size / 2**20:.1f} MiB, over the {max_bytes / 2**20:g} MiB limit of "
                                 "this kind of file (the limit bounds memory and time)")


def check_input_path(path: str | Path, max_bytes: int = MAX_INPUT_BYTES) -> None:
    """Refuse, without opening it, an existing input that is not a regular file or a folder, or a file over
    ``max_bytes``; a missing path or a folder passes (its reader says what it expects).

    Raises:
        InputRefused: a FIFO, a device, a socket, or a file over the bound.
    """
    try:
        st = os.stat(path)
    except OSError:
        return
    if not stat.S_ISDIR(st.st_mode):
        _check_input(path, st, max_bytes)


def read_input_bytes(path: str | Path, max_bytes: int = MAX_INPUT_BYTES) -> bytes:
    """The content of the regular file ``path``, at most ``max_bytes`` of it.

    The file is checked before it is opened, opened without blocking (a FIFO swapped in meanwhile cannot hang the
    open) and checked again on the open descriptor; the read stops one byte past the bound (a file that grows).

    Raises:
        FileNotFoundError, IsADirectoryError: as ``open`` would.
        InputRefused: not a regular file (FIFO, device, socket), or larger than ``max_bytes``.
        OSError: the read failed.
    """
    _check_input(path, os.stat(path), max_bytes)
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        _check_input(path, os.fstat(fd), max_bytes)
        os.set_blocking(fd, True)
        chunks: list[bytes] = []
        size = 0
        while size <= max_bytes:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    finally:
        os.close(fd)
    if size > max_bytes:
        raise InputRefused(path, f"is over the {max_bytes / 2**20:g} MiB limit of this kind of file (the limit "
                                 "bounds memory and time)")
    return b"".join(chunks)


def read_input_text(path: str | Path, max_bytes: int = MAX_INPUT_BYTES) -> str:
    """:func:`read_input_bytes` decoded as UTF-8 (a byte-order mark, as Excel writes, is dropped).

    Raises:
        UnicodeDecodeError: not UTF-8 text; and as :func:`read_input_bytes`.
    """
    return read_input_bytes(path, max_bytes).decode("utf-8-sig")


class LockHeld(Exception):
    """Another process holds an :class:`ExclusiveLock`; ``holder`` is the text it wrote in the lock file ('' if
    none)."""

    def __init__(self, path: Path, holder: str) -> None:
        self.path, self.holder = path, holder
        super().__init__(f"{path} is held by {holder or 'another process'}")


class ExclusiveLock:
    """An exclusive ``flock`` on ``path`` (created if missing) for this process, with ``holder`` written in the file.

    Args:
        path: the lock file.
        holder: what a refused process reads about this one (its pid, its command line).
        mode: the lock file's mode, set on a file this user owns (0o666 lets another user's process take the lock
            after this one; the umask would narrow it).

    Raises:
        LockHeld: another process holds it (nothing is taken).
        OSError: the file cannot be opened.
    """

    def __init__(self, path: str | Path, holder: str, mode: int = 0o644) -> None:
        self.path = Path(path)
        self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT, mode)
        try:
            if os.fstat(self.fd).st_uid == os.getuid():
                os.fchmod(self.fd, mode)
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            text = os.pread(self.fd, 4096, 0).decode(errors="replace").strip()
            os.close(self.fd)
            raise LockHeld(self.path, text) from None
        except BaseException:
            os.close(self.fd)
            raise
        os.ftruncate(self.fd, 0)
        os.pwrite(self.fd, holder.encode(), 0)

    def release(self) -> None:
        """Drop the lock (closing the descriptor drops the flock); safe to call twice."""
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
