"""Atomic writes: every file fdigen writes goes through :func:`write_text` or
:func:`write_bytes` (or :func:`atomic_path` for writers that take a path).

The data goes into a temporary file in the folder of the destination, is flushed to disk,
and replaces the destination with ``os.replace``: a reader sees the old file or the new
one, never a part (a full disk or a crash leaves the old file as it was). A destination
that is a symbolic link is followed: its *target* is replaced, the link stays. An existing
destination keeps its permission bits; a new one gets ``0o666 & ~umask`` like ``open``.
A destination that exists and is not a regular file (a device such as ``/dev/null``, a
FIFO, a socket) is refused (:class:`NotRegularFileError`): replacing it would destroy it
(as root, ``-o /dev/null`` turned the null device into a CSV file). A process killed
mid-write (SIGKILL) leaves its temporary file; the next write of the same destination
removes such leftovers older than an hour.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from pathlib import Path

from fdigen.errors import FdigenError


def resolve_target(path) -> Path:
    """The file a write to ``path`` must replace: symbolic links followed (even dangling
    ones), the folder made absolute."""
    p = Path(path)
    seen = 0
    while p.is_symlink():
        seen += 1
        if seen > 40:
            raise OSError(f"too many levels of symbolic links: {path}")
        link = Path(os.readlink(p))
        p = link if link.is_absolute() else p.parent / link
    return Path(os.path.abspath(p))


class NotRegularFileError(FdigenError):
    """The destination exists and is not a regular file: an atomic write would replace
    (destroy) it."""


def check_regular(target: Path) -> None:
    """Raise :class:`NotRegularFileError` when ``target`` exists and is not a regular file
    (symbolic links already resolved by :func:`resolve_target`)."""
    try:
        st = os.stat(target)
    except FileNotFoundError:
        return
    if not stat.S_ISREG(st.st_mode):
        kind = ("a folder" if stat.S_ISDIR(st.st_mode) else
                "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else
                "a FIFO" if stat.S_ISFIFO(st.st_mode) else
                "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
        raise NotRegularFileError(
            f"{target} is {kind}, not a regular file: fdigen writes a file by replacing it "
            "atomically, which would destroy it; name a file")


#: A temporary file of an atomic write older than this (seconds) was left by a process
#: killed mid-write (SIGKILL runs no cleanup); the next write of the same file removes it.
STALE_SECONDS = 3600.0


def _remove_stale_temps(target: Path) -> None:
    """Remove the temporary files an earlier write of ``target`` left behind when it was
    killed: named as :func:`tempfile.mkstemp` names ours (``.<name>.<8 random
    characters><suffix>``), regular files of this user, older than :data:`STALE_SECONDS`
    (a concurrent write's is younger). A killed ``discover`` left a 0-byte
    ``.discover.png.<random>.png`` that no later run removed."""
    import re
    import time

    pattern = re.compile(r"\." + re.escape(target.name) + r"\.[a-z0-9_]{8}(\.tmp|"
                         + re.escape(target.suffix or ".tmp") + r")\Z")
    try:
        entries = list(os.scandir(target.parent))
    except OSError:
        return
    now = time.time()
    for entry in entries:
        if not pattern.match(entry.name):
            continue
        try:
            st = entry.stat(follow_symlinks=False)
            if (stat.S_ISREG(st.st_mode) and st.st_uid == os.getuid()
                    and now - st.st_mtime > STALE_SECONDS):
                os.unlink(entry.path)
        except OSError:
            continue


def _mode_for(target: Path) -> int:
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


@contextlib.contextmanager
def atomic_path(path, suffix: str = ""):
    """A temporary path to write (by any writer: savefig, to_csv...), moved onto ``path``'s
    target when the block ends without an exception, removed otherwise.

    Yields
    ------
    Path
        In the target's folder; its name ends with ``suffix`` (or the target's suffix) so
        that writers choosing a format by extension still do.
    """
    target = resolve_target(path)
    check_regular(target)
    mode = _mode_for(target)
    _remove_stale_temps(target)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.",
                               suffix=suffix or target.suffix)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        os.chmod(tmp, mode)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


def write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see the module docstring); returns the target."""
    target = resolve_target(path)
    check_regular(target)
    mode = _mode_for(target)
    _remove_stale_temps(target)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target


def write_text(path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically; returns the target."""
    return write_bytes(path, text.encode(encoding))
