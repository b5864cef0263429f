"""Error handling of the ``fdigen`` command line.

Holds ``_fail`` (print one line ``fdigen: error: ...`` and exit) and ``_Group``, the
click group class of ``fdigen`` that turns

* an :class:`~fdigen.errors.FdigenError` or a click usage error (a bad option value) into
  such a line with exit status 2,
* Ctrl-C into ``fdigen: interrupted`` with exit status 130 (no traceback),
* a write error on standard output (``> /dev/full``, a closed pipe) into one line on
  standard error with exit status 2 (a closed pipe: status 141, silently),
* any other exception (an fdigen bug) into one line with exit status 3;

no traceback unless ``FDIGEN_DEBUG=1``. When the command line holds ``--json``, every
failure also prints a JSON object on standard output::

    {"error": {"message": "...", "kind": "ModelFileError", "exit_code": 2}}
"""

from __future__ import annotations

import errno
import json
import os
import sys

import click

from fdigen.errors import FdigenError, shown

#: Exit status of an interrupted command (128 + SIGINT), as shells report it.
EXIT_INTERRUPTED = 130


class _Failure(Exception):
    """Raised by :func:`_fail`; carries the message and exit status to the group."""

    def __init__(self, message: str, code: int, kind: str = "usage"):
        super().__init__(message)
        self.message, self.code, self.kind = message, code, kind


def echo(message="", **kwargs) -> None:
    """``click.echo`` of a line that may hold text from an input (a file name, a model's
    name): non-printable characters are escaped (:func:`fdigen.errors.shown`)."""
    click.echo(shown(message) if isinstance(message, str) else message, **kwargs)


def progress_printer(as_json: bool):
    """The progress callback of a long command: lines on standard error, also under
    ``--json`` when standard error is a terminal (a user's output-error discovery ran 10
    minutes under ``--json`` without a line), never into a captured stream that a caller
    reads the JSON from beside it."""
    if as_json and not sys.stderr.isatty():
        return None
    return lambda msg: echo(msg, err=True)


def _fail(message: str, code: int = 2, kind: str = "usage"):
    """Fail the running command with ``message`` (exit ``code``)."""
    raise _Failure(message, code, kind)


def _silence_stdout() -> None:
    """Point standard output at /dev/null (after a write error, so that the interpreter's
    final flush does not fail again)."""
    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())
        os.close(fd)
    except (OSError, ValueError, AttributeError):
        pass


def _wants_json(ctx) -> bool:
    protected = (ctx._protected_args if hasattr(ctx, "_protected_args")
                 else ctx.protected_args)
    args = list(protected or ()) + list(ctx.args or ())
    return "--json" in args


def _finish(message: str, code: int, kind: str, as_json: bool):
    """Print the failure (a line on stderr; with --json also the JSON object on stdout)
    and exit with ``code``."""
    message = shown(message)
    if as_json:
        try:
            sys.stdout.write(json.dumps({"error": {"message": message, "kind": kind,
                                                   "exit_code": code}}) + "\n")
            sys.stdout.flush()
        except (OSError, ValueError):
            _silence_stdout()
    try:
        click.echo(f"fdigen: {message}" if kind == "interrupted" else
                   f"fdigen: error: {message}", err=True)
    except (OSError, ValueError):
        pass
    sys.exit(code)


def _stop_on_stdout_error(exc: OSError) -> None:
    """Exit for a failed write of standard output: quietly (141) on a closed pipe
    (`fdigen ... | head`), else one error line, exit 2; return for any other error."""
    if exc.errno == errno.EPIPE:
        _silence_stdout()
        sys.exit(141)
    if _is_stdout_error(exc):
        _silence_stdout()
        _finish(f"cannot write to standard output ({exc.strerror or exc})", 2,
                "OutputError", False)


class _Group(click.Group):
    def make_context(self, info_name, args, parent=None, **extra):
        # `fdigen --help` and `--version` print while the context is made, before
        # invoke: a full or closed standard output there was a traceback (attack 14)
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except OSError as exc:
            _stop_on_stdout_error(exc)
            raise

    def invoke(self, ctx):
        as_json = _wants_json(ctx)
        try:
            result = super().invoke(ctx)
            sys.stdout.flush()
            return result
        except _Failure as exc:
            _finish(exc.message, exc.code, exc.kind, as_json)
        except FdigenError as exc:
            if isinstance(exc.__cause__, Exception) and not isinstance(
                    exc.__cause__, (FdigenError, OSError)) and getattr(exc, "internal", False):
                # a bug underneath (the build wraps it to name the model): not bad input
                return self._internal(exc, as_json)
            _finish(str(exc), 2, type(exc).__name__, as_json)
        except click.exceptions.Exit:
            raise
        except click.ClickException as exc:
            if not as_json:
                raise
            _finish(exc.format_message(), exc.exit_code, type(exc).__name__, as_json)
        except (KeyboardInterrupt, click.exceptions.Abort):
            _finish("interrupted", EXIT_INTERRUPTED, "interrupted", as_json)
        except OSError as exc:
            _stop_on_stdout_error(exc)
            return self._internal(exc, as_json)
        except Exception as exc:  # an fdigen bug: say so without a traceback
            return self._internal(exc, as_json)

    @staticmethod
    def _internal(exc, as_json):
        if os.environ.get("FDIGEN_DEBUG"):
            raise exc
        _finish(f"internal error ({type(exc).__name__}: {exc}); "
                "rerun with FDIGEN_DEBUG=1 for details", 3, "InternalError", as_json)


def _is_stdout_error(exc: OSError) -> bool:
    """Whether ``exc`` is a failed write of the command's output (no space, I/O error,
    quota): such an error without a file name comes from standard output (fdigen's own
    file writes name their file)."""
    return exc.filename is None and exc.errno in (errno.ENOSPC, errno.EIO, errno.EDQUOT,
                                                  errno.EFBIG)
