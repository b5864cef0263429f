"""The ``fdigen`` command line: a thin layer over the pipeline functions.

Errors fdigen knows about print one line naming the problem and exit with status 2;
nothing prints a traceback unless ``FDIGEN_DEBUG=1``.

This package holds the click group ``main`` (the ``fdigen`` entry point) and registers
the commands, each defined in the module of its concept:

- :mod:`fdigen.cli.errors`: ``_fail`` and ``_Group`` (error handling, exit codes)
- :mod:`fdigen.cli.build_cmds`: ``build``, ``inspect``, ``verify``
- :mod:`fdigen.cli.run_cmds`: ``detect``, ``report``, ``experiments``
- :mod:`fdigen.cli.simulate_cmd`: ``simulate``
- :mod:`fdigen.cli.tune_cmd`: ``tune`` (its text view: :mod:`fdigen.cli.tune_view`)
- :mod:`fdigen.cli.platform_cmds`: the ``platform`` group
- :mod:`fdigen.cli.platform_common`: options and runners shared by ``--platform`` and
  the ``platform`` group
- :mod:`fdigen.cli.discover_cmd`: ``discover``
- :mod:`fdigen.cli.commission_cmd`: ``commission``
- :mod:`fdigen.cli.assurance_cmds`: ``prove``, ``pil``, ``misra``
- :mod:`fdigen.cli.parsing`: the ``--fault``, ``--effect`` and ``--pose`` parsers
- :mod:`fdigen.cli.durations`: the default ``--duration`` of ``simulate`` and ``verify``
  (from the model)

Importing it imports only click and the standard library; every command imports what it
needs when it runs.
"""

from __future__ import annotations

import click

from fdigen.cli.assurance_cmds import misra, pil, prove
from fdigen.cli.build_cmds import build, inspect, verify
from fdigen.cli.commission_cmd import commission
from fdigen.cli.discover_cmd import discover
from fdigen.cli.errors import _fail, _Group
from fdigen.cli.platform_cmds import platform
from fdigen.cli.run_cmds import detect, experiments, report
from fdigen.cli.simulate_cmd import simulate
from fdigen.cli.tune_cmd import tune

__all__ = ["main", "build", "inspect", "verify", "detect", "simulate", "tune", "report",
           "experiments", "platform", "discover", "commission", "prove", "pil", "misra", "_fail", "_Group"]


@click.group(cls=_Group)
@click.version_option(package_name="fdigen")
def main():
    """fdigen: symbolic model-to-code generator for fault detection and isolation."""
    from fdigen.library_log import route_library_output

    route_library_output()   # the libraries' warnings go to a log file, not the output


for _command in (build, inspect, verify, detect, simulate, tune, report, experiments,
                 platform, discover, commission, prove, pil, misra):
    main.add_command(_command)
del _command
