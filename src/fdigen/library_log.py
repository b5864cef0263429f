"""Warnings and log records of the libraries underneath go to a log file, not to the user.

Dask's "Port 8787 is already in use ... Hosting the HTTP server on port N instead",
distributed's scheduler and worker logs, matplotlib's and casadi's warnings and Python
``warnings`` are about fdigen's machinery, not about the user's model or log: the
``fdigen`` command writes them to ``$FDIGEN_CACHE/fdigen.log`` (default
``~/.cache/fdigen/fdigen.log``) and prints only its own output. ``FDIGEN_DEBUG=1`` prints
them on stderr as well. fdigen's own notes about the model
(:class:`fdigen.errors.FdigenNote`, e.g. a symbolic step that fell back to numbers) are
printed as one line ``fdigen: note: ...`` instead.
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
    from fdigen.files.cache_root import cache_root

    return cache_root() / LOG_NAME


def _handlers() -> list[logging.Handler]:
    """A file handler (opened at the first record), and stderr under ``FDIGEN_DEBUG``;
    a null handler if the log file cannot be made."""
    from fdigen.files.trust import untrusted_reason

    handlers: list[logging.Handler] = []
    path = log_path()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # only in a folder private to the user, and never through a link or into a file
        # of another user's (a shared cache folder let another user choose the file)
        if untrusted_reason(path.parent) is not None or (
                os.path.lexists(path) and untrusted_reason(path) is not None):
            raise OSError("log file not private")
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
    _show_fdigen_notes()
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


def _show_fdigen_notes() -> None:
    """Print fdigen's own notes about the user's model (:class:`fdigen.errors.FdigenNote`)
    as one line ``fdigen: note: ...`` on stderr, once each; every other warning keeps
    going to the log file."""
    import warnings

    from fdigen.errors import FdigenNote

    logged = warnings.showwarning
    if getattr(logged, "_fdigen_notes", False):
        return
    shown = set()

    def show(message, category, filename, lineno, file=None, line=None):
        if isinstance(category, type) and issubclass(category, FdigenNote):
            text = str(message)
            if text not in shown:
                shown.add(text)
                print(f"fdigen: note: {text}", file=sys.stderr)
            return
        logged(message, category, filename, lineno, file, line)

    show._fdigen_notes = True
    warnings.showwarning = show


def reroute_if_active() -> bool:
    """:func:`route_library_output` again if this process routes (after a library import
    that added its own handlers); returns whether it does."""
    if _active:
        route_library_output()
    return _active
