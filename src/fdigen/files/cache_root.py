"""The one folder of fdigen's caches: ``$FDIGEN_CACHE``, else ``~/.cache/fdigen``.

Every cache (designs, compiled libraries, compiled plants, over-budget marks, the library
log) reads it here, so one setting means one folder: ``FDIGEN_CACHE='~/fdc'`` had put the
designs under a literal ``./~/fdc`` of the working folder and the compiled libraries under
``$HOME/fdc``; a relative value starting with ``-`` reached the C compiler's command line
as an option. The folder is made absolute, with ``~`` expanded where it can be.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable naming the cache folder.
CACHE_ENV = "FDIGEN_CACHE"


def cache_root() -> Path:
    """``$FDIGEN_CACHE`` (``~`` expanded, absolute), else ``~/.cache/fdigen``."""
    env = os.environ.get(CACHE_ENV)
    if env:
        path = Path(env)
        try:
            path = path.expanduser()
        except RuntimeError:        # ~user of no user, or no home: taken as written
            pass
        return Path(os.path.abspath(path))
    try:
        home = Path.home()
    except RuntimeError:            # no home folder: a private-looking folder of the cwd
        home = Path(os.path.abspath("."))
    return home / ".cache" / "fdigen"
