"""Static relations between sensors (fdigen.design.static_relations): a residual with no
state, ``y_c - h_c(g_D^{-1}(y_D), u)``, added whenever the outputs allow one.

A user's pump tank (tests/data/newuser7/pump_tank.toml) measures the pump's outlet
pressure, ``rho g (1 - wear) (H0 (n/100)^2 - Kc Q |Q|) / 1e5`` bar, beside a flow meter in
mA: the pressure is predicted by the flow meter and the speed at every sample. The design
had no residual reading that relation: the parity residual of the pressure drifts with the
whole plant's parameter spread (threshold 7.7 times its noise), the Kalman filters do not
read the pressure at all.
"""

from pathlib import Path

import numpy as np
import pytest

from fdigen.backends.reference import ReferenceFdi
from fdigen.design.cache import cached_design
from fdigen.design.residual_scale import residual_scales
from fdigen.design.static_relations import static_relations
from fdigen.model.model_file import load_model, parse_model_text
from fdigen.sim.plant import simulate

DATA = Path(__file__).parent / "data" / "newuser7"


def _pump_tank():
    return load_model(DATA / "pump_tank.toml")


def _static(design):
    return [e for e in design.extra_residuals if e["realisation"] == "static relation"]


def test_the_pump_pressure_is_predicted_by_the_flow_meter():
    design = cached_design(_pump_tank())
    (rel,) = _static(design)
    assert rel["check"] == "y_press" and rel["drivers"] == {"Q": "y_flow"}
    name = rel["residual"]
    hit = {f for f, sig in design.signature_table.items() if name in sig}
    # the wear is inside the pressure's map, the flow meter drives it; the leak and the
    # level sensor never reach a relation without dynamics
    assert hit == {"impeller_wear", "flow_drift"}


def test_the_relation_computes_the_pressure_error_and_ignores_the_dynamics():
    """On a simulated log the residual is the pressure minus its map of the flow meter and
    the speed (numpy, from the file's numbers); a pipe 30 % rougher than the model (a
    parameter of the dynamics only) moves the parity residual of the same sensor and
    leaves the relation at its noise level."""
    model = _pump_tank()
    design = cached_design(model)
    name = _static(design)[0]["residual"]
    k = design.residual_names.index(name)
    kp = design.residual_names.index("Rpress")
    noise = residual_scales(design)[name]["noise_level"]
    p = {q.name: q.value for q in model.parameters}
    results = {}
    for label, params in (("nominal", None), ("rough pipe", {"Kf": 1.3 * p["Kf"]})):
        sim = simulate(model, 300.0, parameters=params, seed=3)
        out = ReferenceFdi(design).run(sim.u, sim.y)
        results[label] = out
        q = (75 * sim.y[:, 0] / 8 - 75 / 2) / 60000
        n = sim.u[:, 0]
        head = p["H0"] * (n / 100) ** 2 - p["Kc"] * q * np.abs(q)
        expected = sim.y[:, 2] - p["rho"] * p["g"] * head / 1e5
        np.testing.assert_allclose(out["r"][:, k], expected, rtol=0, atol=1e-12)
        # the relation's level is the sensors' noise whatever the dynamics do
        assert 0.8 * noise < np.std(out["r"][:, k]) < 1.3 * noise, (label, noise)
    drift = [np.sqrt(np.mean(results[lab]["r"][:, kp] ** 2)) for lab in ("nominal", "rough pipe")]
    assert drift[1] > 3 * drift[0]


@pytest.mark.parametrize("rewrite", [
    # the pressure in Pa instead of bar (its noise, threshold and the parity's with it)
    (('expr = "rho*g*Hp/1e5",        noise_std = 0.01', 'expr = "rho*g*Hp",        noise_std = 1000'),
     ("Rpress = 7.72e-2", "Rpress = 7720"), ("R3 = 0.251", "R3 = 25100")),
    # the flow meter in L/min instead of mA
    (('expr = "4 + 16*Q/150",        noise_std = 0.02', 'expr = "Q",        noise_std = 0.1875'),
     ("test_size = 0.3", "test_size = 2.8")),
])
def test_the_same_relation_in_other_units(rewrite):
    """Units are spelling: the relation, its drivers and the whole signature table are the
    same with the pressure in Pa or the flow in L/min."""
    text = (DATA / "pump_tank.toml").read_text()
    other = text
    for old, new in rewrite:
        assert old in other
        other = other.replace(old, new)
    a = cached_design(parse_model_text(text, source="bar.toml"))
    b = cached_design(parse_model_text(other, source="other.toml"))
    assert a.signature_table == b.signature_table
    assert [(e["check"], e["drivers"]) for e in _static(a)] == \
           [(e["check"], e["drivers"]) for e in _static(b)]


TRIPLEX = """
[model]
name = "triplex_tank"

[parameters]
A  = { value = 0.2, unit = "m^2" }
Cd = { value = 2e-3, unit = "m^2.5/s", uncertain = true }

[states]
h = { unit = "m", range = [0.2, 1.2], limits = [0.0, 2.0] }

[inputs]
q = { unit = "m^3/s", range = [0.0, 4e-3], column = "q" }

[dynamics]
h = "(q - Cd*sqrt(h))/A"

[outputs]
ya = { expr = "h",             noise_std = 1e-3, unit = "m",  column = "ya" }
yb = { expr = "100*h",         noise_std = 0.1,  unit = "cm", column = "yb" }
yc = { expr = "4 + 16*h/1.5",  noise_std = 0.01, unit = "mA", column = "yc" }

[faults.fa]
location = "sensor"
target = "ya"
term = "fa"
class = "a"
test_size = 0.02

[faults.fb]
location = "sensor"
target = "yb"
term = "fb"
class = "b"
test_size = 2.0

[faults.fc]
location = "sensor"
target = "yc"
term = "fc"
class = "c"
test_size = 0.2

[operating_point]
h = 0.64
q = 1.6e-3

[fdi]
sample_time = 0.5
window = 20
"""


def test_three_sensors_of_one_level_give_each_pair_its_relation():
    """Three transmitters of one level (m, cm, mA): each pair of them is a relation (its
    mirror dropped), so each offset has its own pair of relations and the three are told
    apart strongly (no signature inside another)."""
    model = parse_model_text(TRIPLEX, source="triplex.toml")
    faults = [f.name for f in model.faults]
    found = static_relations(model, faults)
    sigs = [frozenset(f for f, on in sig.items() if on) for _, _, sig in found]
    assert sorted(map(sorted, sigs)) == [["fa", "fb"], ["fa", "fc"], ["fb", "fc"]]
    per_fault = {f: {k for k, s in enumerate(sigs) if f in s} for f in faults}
    for f in faults:
        for g in faults:
            if f != g:
                assert not per_fault[f] <= per_fault[g]


def test_shipped_models_have_no_static_relation_outside_the_voter():
    """The cylinder's redundant position sensors are the voter's; the other shipped models
    have one sensor per state: their designs are unchanged."""
    for name in ("pneumatic_cylinder", "three_tank", "dc_motor", "heat_exchanger"):
        assert _static(cached_design(load_model(name))) == []
