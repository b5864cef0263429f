"""click parameter types for the values every command checks before it starts.

A bad value is a usage error naming the option (``Invalid value for '--duration': ...``,
exit status 2), never a traceback or a long run on nonsense.
"""

from __future__ import annotations

import math

import click


class FiniteFloat(click.ParamType):
    """A finite float (no ``nan``/``inf``), optionally ``> 0``.

    Parameters
    ----------
    positive : bool
        Require ``x > 0``.
    """

    name = "number"

    def __init__(self, positive: bool = True):
        self.positive = positive

    def convert(self, value, param, ctx):
        if isinstance(value, float) and math.isfinite(value) and \
                (value > 0 or not self.positive):
            return value
        try:
            x = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(x):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        if self.positive and not x > 0:
            self.fail(f"{value!r} must be greater than 0", param, ctx)
        return x


#: A duration, a time step: finite and > 0.
POSITIVE_SECONDS = FiniteFloat(positive=True)
#: A count of at least 1 (points, runs, workers).
COUNT = click.IntRange(min=1)
#: healthy runs of a threshold campaign: a spread needs at least two
RUNS = click.IntRange(min=2)


class SchedulerAddress(click.ParamType):
    """``synchronous`` or the address of a Dask scheduler, ``SCHEME://HOST:PORT`` with a
    scheme Dask speaks (``tcp``, ``tls``, ``ws``, ``wss``, ``inproc``, ``ucx``): a bare
    ``host:port`` or an unknown scheme is a usage error (Dask would fail later with a
    confusing message, or wait)."""

    name = "address"
    SCHEMES = ("tcp", "tls", "ws", "wss", "inproc", "ucx")

    def convert(self, value, param, ctx):
        text = str(value).strip()
        if text == "synchronous":
            return text
        scheme, sep, rest = text.partition("://")
        if not sep:
            self.fail(f"{value!r} has no scheme; write tcp://{text} (or 'synchronous')",
                      param, ctx)
        if scheme not in self.SCHEMES:
            self.fail(f"{value!r}: unknown scheme {scheme!r} (one of "
                      f"{', '.join(self.SCHEMES)})", param, ctx)
        if scheme != "inproc":
            host, colon, port = rest.rpartition(":")
            if not colon or not host or not port.isdigit() or not 0 < int(port) < 65536:
                self.fail(f"{value!r}: expected {scheme}://HOST:PORT with a port in "
                          "1..65535", param, ctx)
        return text


#: ``--scheduler``: ``synchronous`` or ``SCHEME://HOST:PORT``.
SCHEDULER = SchedulerAddress()


def max_local_workers() -> int:
    """Most local Dask worker processes accepted: 4 per core (at least 8); each is a
    Python process of ~150 MB that compiles the C core."""
    import os

    return max(8, 4 * (os.cpu_count() or 1))


#: ``--workers``: 1 .. :func:`max_local_workers`.
WORKERS = click.IntRange(min=1, max=max_local_workers())
