"""Is a cache folder (or file) private to the current user?

A cache that is loaded with :mod:`pickle` (or a shared library that is ``dlopen``-ed) runs
code: it must come from a folder no other user can write. :func:`untrusted_reason` says
why a path fails that test (or ``None`` when it passes): it must be owned by the current
user and writable by neither group nor others.
"""

from __future__ import annotations

import os
import stat


def reason_for_stat(st: os.stat_result, path) -> str | None:
    """Why the file or folder with status ``st`` is not private (``None`` if it is)."""
    if st.st_uid != os.getuid():
        return f"{path} is owned by uid {st.st_uid}, not by the current user ({os.getuid()})"
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"{path} is writable by other users (mode {stat.S_IMODE(st.st_mode):04o})"
    return None


def untrusted_reason(path) -> str | None:
    """Why ``path`` (not followed if a symbolic link) is not private; ``None`` if it is.

    A symbolic link is refused: its target could be anywhere.
    """
    try:
        st = os.lstat(path)
    except OSError as exc:
        return f"{path}: {exc.strerror}"
    if stat.S_ISLNK(st.st_mode):
        return f"{path} is a symbolic link"
    return reason_for_stat(st, path)
