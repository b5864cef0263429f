"""Error handling of the ``fdigen`` command line.

Holds ``_fail`` (print one line ``fdigen: error: ...`` and exit) and ``_Group``, the
click group class of ``fdigen`` that turns an :class:`~fdigen.errors.FdigenError` into
such a line with exit status 2 and any other exception (an fdigen bug) into one with exit
status 3; no traceback unless ``FDIGEN_DEBUG=1``.
"""

from __future__ import annotations

import os
import sys

import click

from fdigen.errors import FdigenError


def _fail(message: str, code: int = 2):
    click.echo(f"fdigen: error: {message}", err=True)
    sys.exit(code)


class _Group(click.Group):
    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except FdigenError as exc:
            _fail(str(exc))
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except Exception as exc:  # an fdigen bug: say so without a traceback
            if os.environ.get("FDIGEN_DEBUG"):
                raise
            _fail(f"internal error ({type(exc).__name__}: {exc}); "
                  "rerun with FDIGEN_DEBUG=1 for details", 3)
