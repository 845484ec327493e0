"""Safe file access: inputs must be regular files of bounded size; outputs are written atomically.

Reading (:func:`open_regular`): the file is opened without blocking and checked with ``fstat``
before any byte is read, so a FIFO named ``x.bvh`` or a link to ``/dev/zero`` is refused at
once instead of blocking or reading without end, and a file larger than the caller's cap is
refused before it is read.

Writing (:func:`write_bytes_atomic`): the data goes to a temporary file ``.tmp-*`` in the
target's folder, which is flushed to disk (``fsync``), given the mode a new file gets under
the process's umask (``0666 & ~umask``) and renamed over the target; the folder is then
synced so that the rename survives a power cut (a symbolic link is written through, to the
file it points to). Until the rename the target keeps its old
content; afterwards it has the new one, never a mix (``kill -9`` at any point included). The
temporary file is removed on every error, on Ctrl+C and on SIGTERM (received in the main
thread while writing; the signal is then handled as before).
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import stat
import tempfile
import threading

from ..errors import UserError

TEMP_PREFIX = ".tmp-"


def open_regular(path: str | os.PathLike, max_bytes: int | None = None, what: str = "file"):
    """Open ``path`` for binary reading if it is a regular file of at most ``max_bytes``.

    Raises :class:`UserError` naming the path for a missing or unreadable file, a folder, a
    FIFO, a device or socket, or a file over the cap. Returns the open binary file object.
    """
    path = os.fspath(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise UserError(path, f"cannot read file ({e.strerror or e})") from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise UserError(path, f"cannot read file (a folder, not a {what})")
        if not stat.S_ISREG(st.st_mode):
            kind = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode)
                    or stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode) else "special")
            raise UserError(path, f"not a regular file ({kind}); expected a {what}")
        if max_bytes is not None and st.st_size > max_bytes:
            raise UserError(path, f"{what} too large ({st.st_size} bytes; at most {max_bytes})")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_regular(path: str | os.PathLike, max_bytes: int, what: str = "file") -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (see :func:`open_regular`)."""
    with open_regular(path, max_bytes, what) as f:
        try:
            data = f.read(max_bytes + 1)
        except OSError as e:
            raise UserError(os.fspath(path), f"cannot read {what} ({e.strerror or e})") from None
    if len(data) > max_bytes:  # grew while being read
        raise UserError(os.fspath(path), f"{what} too large (more than {max_bytes} bytes)")
    return data


def umask() -> int:
    """The process's umask (from /proc on Linux, without changing it; else set and restored)."""
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def _sigterm_raises():
    """While active (main thread only), SIGTERM raises SystemExit(143) so cleanup code runs."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    try:
        previous = signal.getsignal(signal.SIGTERM)
    except (ValueError, AttributeError):  # pragma: no cover - no signals here
        yield
        return

    def handler(signum, frame):
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


def _fsync_folder(folder: str) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:  # pragma: no cover - a folder we cannot open (some platforms)
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - file systems without directory fsync
        pass
    finally:
        os.close(fd)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically and durably (see the module docstring).

    A symbolic link is written through: the file it points to (after every link of the chain)
    gets the data (and the new file's mode) and the link stays; the rename alone would have
    replaced the link by a file. A loop of links raises ``OSError`` (ELOOP).

    Raises ``OSError`` (the caller names the file) for a missing or read-only folder, a full
    disk and the like; no temporary file is left behind and an existing file stays as it was.
    """
    path = os.fspath(path)
    if os.path.islink(path):
        path = os.path.realpath(path)
        if os.path.islink(path):  # realpath stops inside a loop of links
            raise OSError(errno.ELOOP, os.strerror(errno.ELOOP), path)
    folder = os.path.dirname(os.path.abspath(path))
    with _sigterm_raises():
        fd, tmp = tempfile.mkstemp(prefix=TEMP_PREFIX, dir=folder)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fchmod(f.fileno(), 0o666 & ~umask())
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
    _fsync_folder(folder)
