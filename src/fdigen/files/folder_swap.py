"""Replacing an output folder as one step, and recovering from a build killed midway.

A build writes its files into a hidden temporary folder beside the destination
(``.<name>-<random>``, marked with :data:`TMP_MARK` while it is being written) and then
swaps it with the destination:

* :func:`replace_folder` exchanges the two folders atomically with Linux's
  ``renameat2(RENAME_EXCHANGE)`` (called through ctypes): a SIGKILL at any moment leaves
  either the old or the new folder in place, never none. Where the call is missing
  (another OS, an old kernel, a file system without it) the old folder is renamed aside
  (``.<name>-old-<pid>``) and the new one into place: two renames, with a window in
  between that :func:`recover_folder` closes on the next build.
* :func:`recover_folder` (run under the build lock, before the next build writes) puts
  the set-aside folder back when the destination is missing, and removes the hidden
  folders of earlier, interrupted builds: only those fdigen made, by name *and* content
  (:func:`is_own_folder`), never a user's folder that happens to share the prefix, nor a
  user's copy of a generated folder (which carries the stamp) kept beside it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import re
import shutil
from pathlib import Path
from typing import Callable

#: Marker file of a temporary build folder still being written.
TMP_MARK = ".fdigen-tmp"
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def _renameat2():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                   ctypes.c_uint]
    fn.restype = ctypes.c_int
    return fn


def exchange_paths(a, b) -> bool:
    """Swap the two existing paths ``a`` and ``b`` atomically (``renameat2`` with
    ``RENAME_EXCHANGE``); ``False`` when the system cannot (nothing changed then)."""
    fn = _renameat2()
    if fn is None:
        return False
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(a), None, str(b))


def replace_folder(tmp: Path, target: Path) -> None:
    """Put the finished folder ``tmp`` at ``target`` (see the module docstring); the old
    ``target`` is removed."""
    (tmp / TMP_MARK).unlink(missing_ok=True)
    if not os.path.lexists(target):
        os.replace(tmp, target)
        return
    if exchange_paths(tmp, target):
        _remove(tmp, target.name)                       # now the old folder
        return
    backup = target.parent / f".{target.name}-old-{os.getpid()}"
    os.replace(target, backup)
    os.replace(tmp, target)
    _remove(backup, target.name)


def _remove(old: Path, name: str) -> None:
    """Delete the replaced folder ``old``: renamed first to ``.<name>-deleting-<random>``,
    a name only this step gives, so that a removal killed halfway (its stamp already
    gone: security round 4) is still recognised and finished by the next build."""
    import secrets

    doomed = old.parent / f".{name}-deleting-{secrets.token_hex(4)}"
    try:
        os.replace(old, doomed)
    except OSError:
        doomed = old
    shutil.rmtree(doomed, ignore_errors=True)


def _deleting_name(path: Path, name: str) -> bool:
    """``.<name>-deleting-<random>`` (:func:`_remove`'s folder being deleted)."""
    return re.fullmatch(re.escape(f".{name}-deleting-") + r"[0-9a-f]{8}",
                        path.name) is not None


def _temporary_name(path: Path, name: str) -> bool:
    """``.<name>-`` and the 8 characters ``tempfile.mkdtemp`` appends."""
    return re.fullmatch(re.escape(f".{name}-") + r"[a-z0-9_]{8}", path.name) is not None


def _set_aside_name(path: Path, name: str) -> bool:
    """``.<name>-old-<pid>`` (:func:`replace_folder`'s set-aside old build)."""
    return re.fullmatch(re.escape(f".{name}-old-") + r"[0-9]+", path.name) is not None


def is_own_folder(path: Path, name: str, is_build: Callable[[Path], bool]) -> bool:
    """Whether the hidden folder ``path`` beside ``<out>/<name>`` is one fdigen made.

    Both its name and its content must say so: a temporary build folder
    (``.<name>-<random>``) still marked :data:`TMP_MARK`, a replaced folder whose removal
    was interrupted (``.<name>-deleting-<random>``, a name only :func:`_remove` gives), or
    a temporary or set-aside
    folder (``.<name>-old-<pid>``) holding a complete build (``is_build``: a valid stamp
    of ``name`` whose manifest lists every file there). A user's ``.<name>-backup`` copy
    of a generated folder, or any folder with a file added, is never one.
    """
    if not path.is_dir() or path.is_symlink():
        return False
    if _deleting_name(path, name):
        return True
    if _temporary_name(path, name) and (path / TMP_MARK).is_file():
        return True
    return (_temporary_name(path, name) or _set_aside_name(path, name)) and is_build(path)


def recover_folder(out: Path, name: str, is_build: Callable[[Path], bool]) -> list[str]:
    """Repair ``out`` after an interrupted build of ``name`` (call under the build lock).

    ``is_build(folder)`` says whether a folder holds a complete build of ``name`` and
    nothing else (:func:`fdigen.stamp.is_complete_build`).

    Returns
    -------
    list of str
        What was done (for messages and tests).
    """
    done = []
    if not out.is_dir():
        return done
    target = out / name
    own = sorted((p for p in out.glob(f".{name}-*") if is_own_folder(p, name, is_build)),
                 key=lambda p: p.stat().st_mtime, reverse=True)
    if not os.path.lexists(target):
        backups = [p for p in own if _set_aside_name(p, name)]
        if backups:
            os.replace(backups[0], target)
            own.remove(backups[0])
            done.append(f"restored {target} from {backups[0].name}")
    for p in own:
        shutil.rmtree(p, ignore_errors=True)
        done.append(f"removed {p.name}")
    return done
