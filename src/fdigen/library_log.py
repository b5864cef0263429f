"""Warnings and log records of the libraries underneath go to a log file, not to the user.

Dask's "Port 8787 is already in use ... Hosting the HTTP server on port N instead",
distributed's scheduler and worker logs, matplotlib's and casadi's warnings and Python
``warnings`` are about fdigen's machinery, not about the user's model or log: the
``fdigen`` command writes them to ``$FDIGEN_CACHE/fdigen.log`` (default
``~/.cache/fdigen/fdigen.log``) and prints only its own output. ``FDIGEN_DEBUG=1`` prints
them on stderr as well.
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

#: Loggers of the libraries whose records go to the log file.
LIBRARY_LOGGERS = ("py.warnings", "distributed", "dask", "tornado", "asyncio", "matplotlib",
                   "casadi", "bokeh", "fontTools", "PIL")

#: Name of the log file in fdigen's cache folder.
LOG_NAME = "fdigen.log"

_FORMAT = "%(asctime)s %(process)d %(name)s %(levelname)s: %(message)s"

#: Whether this process routes the libraries' output (set by the ``fdigen`` command; a
#: program using fdigen as a library keeps its own logging).
_active = False


def log_path() -> Path:
    """``$FDIGEN_CACHE/fdigen.log``, else ``~/.cache/fdigen/fdigen.log``."""
    root = Path(os.environ.get("FDIGEN_CACHE", Path.home() / ".cache" / "fdigen"))
    return root / LOG_NAME


def _handlers() -> list[logging.Handler]:
    """A file handler (opened at the first record), and stderr under ``FDIGEN_DEBUG``;
    a null handler if the log file cannot be made."""
    handlers: list[logging.Handler] = []
    path = log_path()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handlers.append(logging.FileHandler(path, encoding="utf-8", delay=True))
    except OSError:
        handlers.append(logging.NullHandler())
    if os.environ.get("FDIGEN_DEBUG"):
        handlers.append(logging.StreamHandler(sys.stderr))
    for h in handlers:
        h.setFormatter(logging.Formatter(_FORMAT))
    return handlers


def route_library_output() -> Path:
    """Send the libraries' warnings and log records (:data:`LIBRARY_LOGGERS`) to the log
    file, in this process; idempotent, and to be called again after importing a library
    that installs its own stderr handler (``distributed`` does at import).

    Returns
    -------
    Path
        The log file.
    """
    global _active
    _active = True
    logging.captureWarnings(True)    # warnings.warn -> the "py.warnings" logger
    handlers = None
    for name in LIBRARY_LOGGERS:
        logger = logging.getLogger(name)
        if getattr(logger, "_fdigen_routed", False) and \
                all(getattr(h, "_fdigen", False) for h in logger.handlers):
            continue
        if handlers is None:
            handlers = _handlers()
            for h in handlers:
                h._fdigen = True
        for h in list(logger.handlers):
            logger.removeHandler(h)
        for h in handlers:
            logger.addHandler(h)
        logger.propagate = False
        logger._fdigen_routed = True
    return log_path()


def reroute_if_active() -> bool:
    """:func:`route_library_output` again if this process routes (after a library import
    that added its own handlers); returns whether it does."""
    if _active:
        route_library_output()
    return _active
