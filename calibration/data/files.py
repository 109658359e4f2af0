"""Atomic output files: a crash, a full disk or a failed serialisation never leaves a half-written file.

Every file cellcal writes (models, recordings, plans, reports, pages, JSON summaries) goes through
:func:`atomic_open` (or its shorthands :func:`atomic_write_text` and :func:`atomic_write_bytes`):

- the content goes to a temporary file in the same folder, is fsynced, then renamed over the target, so a
  reader sees the old file or the new one, never a mix;
- a new file gets the mode a plain ``open(path, "w")`` would give (0o666 minus the umask); an existing file
  keeps its mode (and, where the process may, its owner);
- a symlink, a folder, a device node, a FIFO or a socket at the target is refused, never replaced (so
  ``--json /dev/full`` does not turn the device into a regular file); an empty path or one under a file is
  refused too. :func:`check_output_path` runs the same checks early, before any work is done;
- a write that fails removes the folders it created for the file.

A command that writes a set of outputs (a report folder and a JSON summary) writes them inside
:func:`staged_outputs`: each file waits under its temporary name beside its destination, and the set is renamed into
place only when the whole command succeeded; on any failure every temporary file and every folder created for the
set is removed, so a full disk leaves nothing half-written (``evaluate --report R --json J`` had left ``J`` and half
of ``R``).

One process at a time: :class:`ExclusiveLock` is an exclusive ``flock`` on a lock file with its holder written in
it, released on :meth:`~ExclusiveLock.release` or by the kernel when the process ends (even by a crash, so no lock is
ever stale): a session folder's collector and a MotoROS controller's driver hold one. The lock file is opened
without following a symlink (``O_NOFOLLOW``) and must be a regular file with a single link, so a link planted where
the lock goes never makes a process truncate or write another file; its mode is never widened. A folder of lock
files shared by several users is refused (:func:`private_folder`).

Every input file (recordings, model files, cell files, plan files, path files, jobs) is read through
:func:`read_input_bytes` (or :func:`read_input_text`): only a regular file is read (a FIFO, a device such as
``/dev/zero`` or a socket is refused before anything is read: opened without blocking, checked, then read), and
never more than its bound of bytes (``MAX_INPUT_BYTES`` unless the reader gives its own), so a huge or endless
input is refused instead of filling memory or hanging.
"""

from __future__ import annotations

import contextlib
import contextvars
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


class _Stage:
    """The outputs of one :func:`staged_outputs` block: temporary files waiting for their names, folders made."""

    def __init__(self) -> None:
        self.files: list[tuple[Path, Path]] = []  # (temporary, destination), in the order written
        self.folders: list[Path] = []  # created for the set, parents first

    def commit(self) -> None:
        for k, (tmp, path) in enumerate(self.files):
            try:
                check_output_path(path)  # not swapped for a symlink or a device meanwhile
                os.replace(tmp, path)
            except (OSError, OutputError) as e:
                for later, _ in self.files[k:]:
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(later)
                done = ", ".join(str(p) for _, p in self.files[:k]) or "none"
                if isinstance(e, OutputError):
                    raise OutputError(path, f"{e.reason}; already in place: {done}") from e
                raise OutputError(path, f"cannot write ({e.strerror or e}); already in place: {done}") from e
        for folder in dict.fromkeys(path.parent for _, path in self.files):
            _fsync_folder(folder)

    def discard(self) -> None:
        for tmp, _ in self.files:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        _remove_folders(self.folders)


_STAGE: contextvars.ContextVar[_Stage | None] = contextvars.ContextVar("cellcal_output_stage", default=None)


@contextlib.contextmanager
def staged_outputs() -> Iterator[None]:
    """Every :func:`atomic_open` (and :func:`make_folders`) inside the block is one set: the files take their names
    together when the block ends without an exception; on an exception every temporary file and every folder the
    block created are removed and the exception propagates. A nested block belongs to the outer one.

    Files written in the block wait under their temporary names until it ends: read one back with
    :func:`read_output_bytes`.

    Raises:
        OutputError: a rename at the end failed (the message names the files already in place; the rest are
            removed).
    """
    if _STAGE.get() is not None:
        yield
        return
    stage = _Stage()
    token = _STAGE.set(stage)
    try:
        yield
    except BaseException:
        stage.discard()
        raise
    finally:
        _STAGE.reset(token)
    stage.commit()


def read_output_bytes(path: str | Path) -> bytes:
    """The bytes of an output written earlier, also while it waits under its temporary name in a
    :func:`staged_outputs` block (a report embeds the plots it has just written)."""
    stage = _STAGE.get()
    if stage is not None:
        for tmp, dest in reversed(stage.files):
            if dest == Path(path):
                return tmp.read_bytes()
    return Path(path).read_bytes()


def make_folders(folder: str | Path) -> list[Path]:
    """Create ``folder`` and its missing parents; returns the ones created (parents first). Inside
    :func:`staged_outputs` they are removed again if the block fails."""
    folder = Path(folder)
    missing: list[Path] = []
    try:
        for f in (folder, *folder.parents):
            if f.exists() or f.is_symlink():
                break
            missing.append(f)
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # a parent that is a file, a name too long, no permission: one line naming the folder
        _remove_folders(missing[::-1])  # the parents it made before failing (each removed only if empty)
        raise OutputError(folder, f"cannot create this folder ({e.strerror or e})") from e
    created = missing[::-1]
    stage = _STAGE.get()
    if stage is not None:
        stage.folders += created
    return created


def _remove_folders(folders: list[Path]) -> None:
    """Remove ``folders`` (parents first in the list), children first, each only if empty."""
    for folder in reversed(folders):
        with contextlib.suppress(OSError):
            os.rmdir(folder)


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
    full disk) the temporary file and the folders made for it are removed, ``path`` is left as it was and the
    exception propagates (an ``OSError`` as :class:`OutputError`). Inside :func:`staged_outputs` the file takes
    its name when the block ends.

    Raises:
        OutputError: the path is refused (see :func:`check_output_path`) or the write failed.
    """
    st = check_output_path(path)  # before Path(): Path("") is the current folder
    path = Path(path)
    stage = _STAGE.get()
    created: list[Path] = []
    try:
        created = make_folders(path.parent)
        fd, tmp = _create_temp(path)
    except OSError as e:
        if stage is None:
            _remove_folders(created)
        raise OutputError(path, f"cannot write ({e.strerror or e})") from e
    try:
        with (os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8", newline="")) as f:
            _keep_owner_and_mode(f.fileno(), st)
            yield f
            f.flush()
            os.fsync(f.fileno())
        check_output_path(path)  # not swapped for a symlink or a device while we wrote
        if stage is not None:
            stage.files.append((tmp, path))  # renamed with the rest of the set
            return
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if stage is None:
            _remove_folders(created)
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
        mode: the mode of a lock file created now (narrowed by the umask; an existing file's mode is kept).

    Raises:
        LockHeld: another process holds it (nothing is taken).
        OSError: the file cannot be opened, or ``path`` is a symlink (ELOOP), not a regular file or a file with
            several links (nothing is written to it).
    """

    def __init__(self, path: str | Path, holder: str, mode: int = 0o644) -> None:
        self.path = Path(path)
        flags = os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
        try:  # O_NONBLOCK: a FIFO planted there must not block the open
            self.fd = os.open(self.path, flags, mode)
        except OSError as e:
            if e.errno == errno.ELOOP:
                raise OSError(errno.ELOOP, "the lock file is a symbolic link; refusing to follow it (remove it)",
                              str(path)) from None
            raise
        try:
            st = os.fstat(self.fd)
            if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
                what = "not a regular file" if not stat.S_ISREG(st.st_mode) else f"a file with {st.st_nlink} links"
                raise OSError(errno.EPERM, f"the lock file is {what}; refusing to use it (remove it)", str(path))
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


def private_folder(path: str | Path, create: bool = True) -> Path:
    """``path`` as a folder only this user can write: created 0700 when missing (with ``create``), refused when it is
    a symlink, not a folder, owned by another user, or writable by the group or others (anyone who can create
    entries in it could plant a link where a file of ours goes).

    Raises:
        OSError: the folder is refused (naming why) or cannot be created.
    """
    path = Path(path)
    if create:
        with contextlib.suppress(FileExistsError):
            path.mkdir(mode=0o700, parents=True)
    st = os.lstat(path)
    if stat.S_ISLNK(st.st_mode) or not stat.S_ISDIR(st.st_mode):
        raise OSError(errno.EPERM, "not a folder (a symlink or a file); refusing to keep lock files there", str(path))
    if st.st_uid != os.geteuid():
        raise OSError(errno.EPERM, f"owned by uid {st.st_uid}, not this user ({os.geteuid()}); refusing to keep "
                                   "lock files there", str(path))
    if st.st_mode & 0o022:
        raise OSError(errno.EPERM, f"writable by other users (mode {stat.S_IMODE(st.st_mode):04o}); refusing to keep "
                                   "lock files there", str(path))
    return path
