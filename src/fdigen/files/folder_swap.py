"""Replacing an output folder as one step, and recovering from a build killed midway.

A build writes its files into a hidden temporary folder beside the destination
(``.<name>-XXXX``, marked with :data:`TMP_MARK` while it is being written) and then
swaps it with the destination:

* :func:`replace_folder` exchanges the two folders atomically with Linux's
  ``renameat2(RENAME_EXCHANGE)`` (called through ctypes): a SIGKILL at any moment leaves
  either the old or the new folder in place, never none. Where the call is missing
  (another OS, an old kernel, a file system without it) the old folder is renamed aside
  (``.<name>-old-<pid>``) and the new one into place: two renames, with a window in
  between that :func:`recover_folder` closes on the next build.
* :func:`recover_folder` (run under the build lock, before the next build writes) puts
  the set-aside folder back when the destination is missing, and removes the hidden
  folders of earlier, interrupted builds: only those fdigen marked as its own (holding
  :data:`TMP_MARK` or the build stamp), never a user's folder that happens to share the
  prefix.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import shutil
from pathlib import Path

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
        shutil.rmtree(tmp, ignore_errors=True)          # now the old folder
        return
    backup = target.parent / f".{target.name}-old-{os.getpid()}"
    os.replace(target, backup)
    os.replace(tmp, target)
    shutil.rmtree(backup, ignore_errors=True)


def is_own_folder(path: Path, stamp: str) -> bool:
    """Whether the hidden folder ``path`` is one fdigen made (a temporary build folder or
    a set-aside old build): it holds :data:`TMP_MARK` or the build stamp ``stamp``."""
    return (path.is_dir() and not path.is_symlink()
            and ((path / TMP_MARK).is_file() or (path / stamp).is_file()))


def recover_folder(out: Path, name: str, stamp: str) -> list[str]:
    """Repair ``out`` after an interrupted build of ``name`` (call under the build lock).

    Returns
    -------
    list of str
        What was done (for messages and tests).
    """
    done = []
    if not out.is_dir():
        return done
    target = out / name
    own = sorted((p for p in out.glob(f".{name}-*") if is_own_folder(p, stamp)),
                 key=lambda p: p.stat().st_mtime, reverse=True)
    if not os.path.lexists(target):
        backups = [p for p in own if p.name.startswith(f".{name}-old-")
                   and (p / stamp).is_file()]
        if backups:
            os.replace(backups[0], target)
            own.remove(backups[0])
            done.append(f"restored {target} from {backups[0].name}")
    for p in own:
        shutil.rmtree(p, ignore_errors=True)
        done.append(f"removed {p.name}")
    return done
