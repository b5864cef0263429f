"""Parsers of the command line's small value languages.

``_parse_fault`` reads ``--fault NAME@T0=SIZE`` (also ``=RATE/s`` and ``=stuck``),
``_parse_effect`` reads ``--effect NAME=VALUE`` and ``_parse_pose`` reads
``fdigen platform ik --pose surge,sway,heave,roll,pitch,yaw``. Each imports what it
needs when called.
"""

from __future__ import annotations

import math

import click

from fdigen.errors import FdigenError


def _parse_pose(text: str, degrees: bool):
    import numpy as np

    from fdigen.platform.geometry import DOF_NAMES

    try:
        q = [float(v) for v in text.replace(";", ",").split(",")]
    except ValueError:
        q = []
    if len(q) != 6 or not all(np.isfinite(q)):
        raise FdigenError(f"--pose: expected 6 numbers '{','.join(DOF_NAMES)}', got {text!r}")
    if degrees:
        q[3:] = [float(np.radians(v)) for v in q[3:]]
    return np.array(q)


def _parse_effect(text: str, model):
    """``NAME=VALUE``: a library effect (fdigen.discover.effects) and its parameter value."""
    from fdigen.discover.effects import get_effect

    name, sep, value = text.partition("=")
    try:
        size = float(value)
    except ValueError:
        raise click.BadParameter(f"expected NAME=VALUE, got {text!r}", param_hint="--effect")
    if not sep:
        raise click.BadParameter(f"expected NAME=VALUE, got {text!r}", param_hint="--effect")
    eff = get_effect(name.strip(), model)
    return eff, {eff.parameter_names[0]: size}


def _parse_parameter(text: str, model) -> tuple[str, float]:
    """``NAME=VALUE``: a parameter of ``model`` and the value the simulated plant has (a
    plant inside its tolerance, a warm coil), finite and within the parameter's bounds."""
    name, sep, value = text.partition("=")
    name = name.strip()
    try:     # plain ASCII decimals: float() also reads 1_0_0_0 and full-width digits
        number = float(value) if value.isascii() and "_" not in value else math.nan
    except ValueError:
        number = math.nan
    if not sep or not math.isfinite(number):
        raise click.BadParameter(f"expected NAME=VALUE with a finite number, got {text!r}",
                                 param_hint="--parameter")
    q = next((q for q in model.parameters if q.name == name), None)
    if q is None:
        raise click.BadParameter(
            f"{name!r} is not a parameter of model {model.name} (parameters: "
            f"{', '.join(q.name for q in model.parameters)})", param_hint="--parameter")
    if q.bounds is not None and not q.bounds[0] <= number <= q.bounds[1]:
        raise click.BadParameter(f"{name} = {number!r} is outside its bounds "
                                 f"[{q.bounds[0]!r}, {q.bounds[1]!r}]",
                                 param_hint="--parameter")
    return name, number


def _parse_fault(text: str):
    """``name@t0=size``, ``name@t0=size/s`` (a ramp: size per second) or
    ``name@t0=stuck`` (a sensor holding its last value)."""
    from fdigen.sim.plant import FaultEvent

    try:
        name, rest = text.split("@", 1)
        t0, size = rest.split("=", 1)
        if size.strip() == "stuck":
            start = float(t0)
            if not (math.isfinite(start) and start >= 0):
                raise ValueError(t0)
            return FaultEvent(name.strip(), start, 0.0, stuck=True)
        ramp = size.endswith("/s")
        start, value = float(t0), float(size[:-2] if ramp else size)
    except ValueError:
        raise click.BadParameter(f"expected NAME@T0=SIZE or NAME@T0=RATE/s, got {text!r}",
                                 param_hint="--fault")
    if not (math.isfinite(start) and start >= 0 and math.isfinite(value)):
        raise click.BadParameter(f"T0 must be a finite time >= 0 and SIZE a finite number, "
                                 f"got {text!r}", param_hint="--fault")
    return FaultEvent(name.strip(), start, value, ramp)
