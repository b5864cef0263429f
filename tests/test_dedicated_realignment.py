"""Parity residuals that cannot mix sensors (``realign = "dedicated"``, docs/isolation.md 6).

Read from the step program itself: the raw measurements each parity residual can depend on,
at this sample or through the FDI state at any later sample (the fixed point of the
dependence through ``z -> z_next``). With the dedicated realignment a parity residual
reads its own sensor and nothing else; with the shared one it reads every parity sensor
(the test would see the mixing).
"""

from __future__ import annotations

import dataclasses

import pytest

from fdigen.design.cache import cached_design
from fdigen.design.fdi_design import fdi_design
from fdigen.model.model_file import builtin_model_path, load_model


def reachable_measurements(design) -> dict:
    """Residual -> names of the raw outputs it depends on, now or through the state."""
    step = design.step
    deps = {s: {s} for s in step.free_inputs()}
    for sym, expr in step.assignments:
        deps[sym] = set().union(*(deps.get(a, set()) for a in expr.free_symbols))
    z = step.inputs["z"]
    y_raw = {s: o.name for s, o in zip(step.inputs["y"], design.model.outputs)}

    def of(expr):
        return set().union(*(deps.get(a, {a}) for a in expr.free_symbols))

    state = {zi: of(e) for zi, e in zip(z, step.outputs["z_next"])}
    while True:          # the state's dependence on earlier samples' measurements
        grown = {zi: d | set().union(*(state[s] for s in d if s in state))
                 for zi, d in state.items()}
        if grown == state:
            break
        state = grown
    out = {}
    for name, r in zip(design.residual_names, step.outputs["r"]):
        d = of(r)
        d |= set().union(*(state[s] for s in d if s in state))
        out[name] = {y_raw[s] for s in d if s in y_raw}
    return out


@pytest.mark.parametrize("hold", [False, True])
@pytest.mark.parametrize("name", ["three_tank", "dc_motor"])
def test_parity_residual_reads_its_own_sensor_only(name, hold):
    """Also with the held correction (docs/isolation.md, section 13): its means are states
    of the block, fed by the block's own innovation."""
    model = load_model(builtin_model_path(name))
    if hold:
        model = dataclasses.replace(model, fdi={**model.fdi, "hold_windows": 1})
    design = cached_design(model)
    assert design.config.realign == "dedicated" and bool(design.config.hold_windows) == hold
    seen = reachable_measurements(design)
    for rname, output in design.config.parity.items():
        assert seen[rname] == {output}, (rname, seen[rname])
    # the shared realignment mixes them: every parity sensor reaches every parity residual
    shared = dataclasses.replace(model, fdi={**model.fdi, "realign": "shared"})
    seen = reachable_measurements(fdi_design(shared))
    for rname in design.config.parity:
        assert seen[rname] == set(design.config.parity.values()), rname
