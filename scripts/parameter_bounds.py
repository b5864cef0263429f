#!/usr/bin/env python3
"""Parameter bounds of a model where the FDI design's stability checks pass.

Usage: python scripts/parameter_bounds.py [MODEL]

For each bounded parameter, the declared bound is checked with the design's own checks
(RK4 step of the parallel model, scheduled Kalman predictions; see
``fdigen.design.parameter_range``), the others nominal; a failing bound is replaced by the
value, found by bisection, where the checks start to fail (3 significant digits, rounded
toward nominal). The corners of the widest bounds are then checked together and, while
one fails, the parameter whose bound needs the smallest move toward nominal for that
corner to pass takes that move (else all are pulled halfway).
Prints the resulting bounds as TOML; the built-in models' ``bounds`` come from it.
"""

from __future__ import annotations

import dataclasses
import math
import sys


def _toward(value, nominal, fraction):
    """The point ``fraction`` of the way from ``value`` to ``nominal`` (geometric for
    positive values)."""
    if value > 0 and nominal > 0:
        return value * (nominal / value) ** fraction
    return value + (nominal - value) * fraction


def main(argv):
    from fdigen.design.fdi_design import fdi_design
    from fdigen.design.parameter_range import (check_parameters, stable_limit,
                                               unstable_bounds)
    from fdigen.model.model_file import load_model

    model = load_model(argv[0] if argv else None)
    design = fdi_design(model)
    bounds = {q.name: list(q.bounds) for q in model.parameters if q.bounds is not None}
    for name in bounds:
        for side in (0, 1):
            bounds[name][side] = stable_limit(design, name, side)
    nominal = {q.name: q.value for q in model.parameters}
    for _ in range(60):
        params = tuple(dataclasses.replace(q, bounds=tuple(bounds[q.name]))
                       if q.name in bounds else q for q in model.parameters)
        trial = dataclasses.replace(design, model=dataclasses.replace(model,
                                                                      parameters=params))
        failures = unstable_bounds(trial)
        if not failures:
            break
        values, msg = failures[0]
        print(f"# corner {values} fails: {msg[:120]}", file=sys.stderr)
        # the parameter whose bound needs the smallest move toward nominal for this
        # corner to pass takes that move (bisection on the fraction of the way)
        best = None
        for name, v in values.items():
            def at(f, name=name, v=v):
                return _toward(v, nominal[name], f)
            if check_parameters(trial, {**values, name: at(1.0)}) is not None:
                continue
            lo, hi = 0.0, 1.0
            while hi - lo > 0.01:
                mid = (lo + hi) / 2
                if check_parameters(trial, {**values, name: at(mid)}) is None:
                    hi = mid
                else:
                    lo = mid
            if best is None or hi < best[1]:
                best = (name, hi, at(hi))
        if best is None:          # no single parameter fixes it: pull them all halfway
            moves = {n: _toward(v, nominal[n], 0.5) for n, v in values.items()}
        else:
            moves = {best[0]: best[2]}
        for name, new in moves.items():
            side = 0 if values[name] <= nominal[name] else 1
            step = math.ceil if side == 0 else math.floor   # 3 digits, toward nominal
            scale = 10.0 ** (math.floor(math.log10(abs(new))) - 2) if new else 1.0
            bounds[name][side] = float(f"{step(new / scale) * scale:.3g}")
    else:
        print("# WARNING: corners still fail after 60 moves", file=sys.stderr)
    for q in model.parameters:
        if q.name in bounds and list(q.bounds) != bounds[q.name]:
            print(f"{q.name}: bounds = {list(q.bounds)} -> {bounds[q.name]}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
