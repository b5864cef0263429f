"""Bounded reads of input files: regular files only, at most a given size.

``/dev/zero``, a FIFO or a terminal never ends; a huge file should not be read into
memory by mistake. :func:`read_bytes` refuses anything that is not a regular file and
any file larger than ``limit`` bytes, with an error naming the file.
"""

from __future__ import annotations

import os
import stat

from fdigen.errors import FdigenError

#: Default size limit of a log (CSV) file [bytes].
LOG_LIMIT = 1 << 30


def check_regular_file(path, *, what: str = "input file", error=FdigenError) -> None:
    """Refuse at once (``error``, the messages of :func:`read_bytes`) a ``path`` that does
    not exist or is not a regular file: commands call it before long work (deriving a
    design), so ``/dev/zero`` or a typo is refused in milliseconds."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        kind = ("a folder" if stat.S_ISDIR(st.st_mode) else
                "not a regular file (a device, FIFO or socket)")
        raise error(f"{path}: cannot read {what}: {kind}")


def read_bytes(path, limit: int, *, what: str = "input file", error=FdigenError) -> bytes:
    """The content of the regular file ``path``, of at most ``limit`` bytes.

    Raises
    ------
    error (default FdigenError)
        If ``path`` cannot be opened, is not a regular file (device, FIFO, folder) or is
        larger than ``limit`` bytes.
    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = ("a folder" if stat.S_ISDIR(st.st_mode) else
                    "not a regular file (a device, FIFO or socket)")
            raise error(f"{path}: cannot read {what}: {kind}")
        if st.st_size > limit:
            raise error(f"{path}: cannot read {what}: larger than {limit} bytes ({st.st_size})")
        with os.fdopen(fd, "rb", closefd=False) as fh:
            # read(n) allocates n bytes first: ask for the file's size (+1 to notice a
            # file that grew), not for the limit
            data = fh.read(min(st.st_size, limit) + 1)
            if len(data) > st.st_size:
                data += fh.read(limit + 1 - len(data))
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror})") from None
    finally:
        os.close(fd)
    if len(data) > limit:
        raise error(f"{path}: cannot read {what}: larger than {limit} bytes")
    return data
