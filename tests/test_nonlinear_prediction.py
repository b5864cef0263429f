"""Kalman filters that predict through the nonlinear model (design/nonlinear_prediction.py).

A rig with Coulomb friction (fdigen's simulator, the library effect at its nominal size),
the built-in cylinder augmented with that effect (as `fdigen discover` writes it): its
Kalman residuals stay at their noise-only level on healthy data, where the linear
(describing-function) prediction does not; the float C core follows; the leaky chamber
(state-dependent reduced coordinates) builds. Bit-identity of the prediction on every
backend: tests/test_verify.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import sympy as sp

from fdigen.backends.c.loader import CFdi
from fdigen.design import observers
from fdigen.design.fdi_design import fdi_design
from fdigen.design.observers import residual_noise_level
from fdigen.discover import effects as fx
from fdigen.discover.augment import augmented_text, check_augmented
from fdigen.model.model_file import builtin_model_path, load_model
from fdigen.sim.plant import simulate

from conftest import RIG

#: a healthy Kalman residual's RMS stays within this factor of its noise-only level
NOISE_FACTOR = 1.3


def _augmented(cylinder, effect, values):
    e = fx.get_effect(effect, cylinder)
    text = augmented_text(builtin_model_path("pneumatic_cylinder").read_text(), cylinder,
                          [e], values)
    return e, check_augmented(text, cylinder, [e], f"{effect}_augmented.toml")


@pytest.fixture(scope="module")
def coulomb(cylinder):
    """The Coulomb-friction rig (10 s healthy run) and the augmented design."""
    values = {"Fc": fx.get_effect("coulomb_friction", cylinder).parameters[0].nominal}
    e, model = _augmented(cylinder, "coulomb_friction", values)
    sim = simulate(cylinder, 10.0, effects=e.plant_effects(cylinder, values), seed=7,
                   substeps=4)
    return fdi_design(model), sim


def _ratios(design, sim):
    out = CFdi(design).run(sim.u, sim.y)
    r = np.asarray(out["r"])[500:]
    return {k.residual: float(np.sqrt(np.mean(r[:, design.residual_names.index(k.residual)]
                                              ** 2)) / residual_noise_level(k))
            for k in design.kalman}, int(np.bitwise_or.reduce(np.asarray(out["flags"])))


def test_coulomb_rig_kalman_residuals_stay_at_noise_level(coulomb, monkeypatch):
    design, sim = coulomb
    assert {k.residual: k.schedule for k in design.kalman} == {
        "R4": "nonlinear", "R5": "nonlinear", "R6": "nonlinear"}
    assert all(k.nonlinear_reason == "non-smooth term in the dynamics" for k in design.kalman)
    ratios, flags = _ratios(design, sim)
    assert flags == 0
    assert all(v < NOISE_FACTOR for v in ratios.values()), ratios
    # the linear (describing-function) prediction of the same model, for contrast
    monkeypatch.setattr(observers, "nonlinear_reason", lambda model, T, drivers=(): None)
    linear = fdi_design(design.model)
    assert {k.schedule for k in linear.kalman} != {"nonlinear"}
    lin_ratios, lin_flags = _ratios(linear, sim)
    assert lin_flags != 0
    # the force balance (R6) and the pressure filter (R5) are far off without it
    assert lin_ratios["R6"] > 5 * ratios["R6"] and lin_ratios["R5"] > 2 * ratios["R5"]


def test_float_core_follows_the_nonlinear_prediction(coulomb):
    """The single-precision C core (a controller's) stays quiet and tracks the double one."""
    design, sim = coulomb
    d_out = CFdi(design).run(sim.u, sim.y)
    f_out = CFdi(design, float_type="float").run(sim.u, sim.y)
    assert int(np.bitwise_or.reduce(np.asarray(f_out["flags"]))) == 0
    for k in design.kalman:
        i = design.residual_names.index(k.residual)
        rd, rf = np.asarray(d_out["rms"])[500:, i], np.asarray(f_out["rms"])[500:, i]
        assert np.max(np.abs(rf - rd)) < 0.05 * np.max(rd), k.residual


def test_leaky_chamber_design_builds_and_stays_quiet(cylinder, tmp_path):
    """A leak to atmosphere from chamber n makes R5's reduced coordinates depend on the
    state (``Pp + c(x) x``...): the nonlinear prediction runs in the coordinates of the
    operating point and lifts them on the voted position and measured pressures. On the
    rig's leak log, discover's default path (augment, build, FDI) goes to the end (it
    stopped with "cannot schedule its prediction") and the augmented design is quiet."""
    e = fx.get_effect("leak_n", cylinder)
    log = RIG / "logs" / "discrepancy_leak_n.csv"
    if log.is_file():
        from fdigen.discover.pipeline import discover
        res = discover(log, out=tmp_path / "out", plot=False).as_dict()
        assert res["effect"] == "leak_n" and res["build"]
        # the original design (no leak) flags the log: R4 and, each re-aligned on its own
        # sensor only, the parity residuals; the augmented design is quiet
        assert res["fdi_flags_after"] == [] and "R4" in res["fdi_flags_before"]
        model = load_model(res["model_file"])
    else:
        _, model = _augmented(cylinder, "leak_n", {"Cl_n": 2e-11})
    design = fdi_design(model)
    kal = {k.residual: k for k in design.kalman}
    assert kal["R5"].reduction.T.free_symbols & set(model.x)
    assert kal["R5"].schedule == "nonlinear"
    sim = simulate(cylinder, 5.0, effects=e.plant_effects(cylinder, {"Cl_n": 2e-11}), seed=3,
                   substeps=4)
    ratios, flags = _ratios(design, sim)
    assert flags == 0 and all(v < NOISE_FACTOR for v in ratios.values()), ratios


def test_sign_friction_is_smoothed_at_the_filter_resolution(cylinder, coulomb, tmp_path):
    """``sign(xdot)`` in place of the library's ``tanh``: no DiracDelta in any Jacobian,
    the prediction switches over a width set by the filter (and RK4), and stays quiet."""
    _, sim = coulomb
    e = fx.get_effect("coulomb_friction", cylinder)
    text = augmented_text(builtin_model_path("pneumatic_cylinder").read_text(), cylinder,
                          [e], {"Fc": e.parameters[0].nominal})
    v_eps = e.text("xdot").split("tanh(xdot/")[1].split(")")[0]
    path = tmp_path / "sign.toml"
    path.write_text(text.replace(f"tanh(xdot/{v_eps})", "sign(xdot)"))
    design = fdi_design(load_model(path))
    assert {k.schedule for k in design.kalman} == {"nonlinear"}
    widths = set()
    for s, expr in design.step.assignments:
        if s.name.startswith("R4_nl"):
            assert not expr.atoms(sp.sign)
            widths |= {1 / float(t.args[0].as_coeff_Mul()[0]) for t in expr.atoms(sp.tanh)}
    assert len(widths) == 1
    # narrower than the library's smoothing (v_eps), wide enough for RK4 at the sub-step
    assert 1e-4 < widths.pop() < float(v_eps)
    ratios, flags = _ratios(design, sim)
    assert flags == 0 and all(v < NOISE_FACTOR for v in ratios.values()), ratios


def test_stiff_friction_gets_more_substeps_in_the_filter(cylinder, tmp_path):
    """A friction switch five times steeper than the library's (slope Fc/(M v_eps) ~ 1e4
    1/s): RK4 at the parity models' 0.5 ms amplifies it, so the filters integrate their
    prediction with the fewest sub-steps that are stable, not the parity models'."""
    e = fx.get_effect("coulomb_friction", cylinder)
    text = augmented_text(builtin_model_path("pneumatic_cylinder").read_text(), cylinder,
                          [e], {"Fc": e.parameters[0].nominal})
    v_eps = e.text("xdot").split("tanh(xdot/")[1].split(")")[0]
    path = tmp_path / "stiff.toml"
    path.write_text(text.replace(f"tanh(xdot/{v_eps})", f"tanh(xdot/{float(v_eps) / 5})"))
    model = load_model(path)
    design = fdi_design(model)
    names = {s.name for s, _ in design.step.assignments}
    substeps = int(model.fdi.get("substeps", 1))
    for k in design.kalman:
        steps = {int(n[len(k.residual) + 3:].split("_")[0]) for n in names
                 if n.startswith(f"{k.residual}_nl") and n[len(k.residual) + 3:][:1].isdigit()
                 and "_z" in n}
        assert max(steps) + 1 > substeps, (k.residual, steps)


def test_nonlinear_filter_of_a_model_without_realignment(tmp_path):
    """A user's tanks (cm, 4-20 mA, guarded sqrt) whose derived filter predicts through the
    nonlinear model, with realignment at its default (off): no reference parallel model
    (there is no re-aligned estimate), the design derives and inspect exits 0 (it crashed
    on the missing Riccati solution); with realignment on, the reference model is added."""
    import tomlkit
    from click.testing import CliRunner

    from fdigen.cli import main

    given = Path(__file__).parent / "data" / "newuser" / "tanks_cm_guarded.toml"
    from fdigen.tune.model_update import fill_missing_thresholds

    # the guard sqrt(max(h2, 0)) never acts on h2's declared 10-30 cm: smooth there, the
    # filter is linear (round 51); declared down to 0 cm the guard acts, and the filter
    # predicts through the nonlinear model
    assert {k.schedule for k in fdi_design(fill_missing_thresholds(
        load_model(given), 1e3)[0]).kalman} == {"operating_point"}
    src = tmp_path / "tanks_cm_guarded.toml"
    text = given.read_text()
    assert 'h2 = { unit = "cm", range = [10.0, 30.0]' in text
    src.write_text(text.replace('h2 = { unit = "cm", range = [10.0, 30.0]',
                                'h2 = { unit = "cm", range = [0.0, 30.0]'))
    res = CliRunner().invoke(main, ["inspect", "--model", str(src)])
    assert res.exit_code == 0, res.output[-1500:]

    design = fdi_design(fill_missing_thresholds(load_model(src), 1e3)[0])
    assert {k.schedule for k in design.kalman} == {"nonlinear"}
    assert not any(n.startswith("parref_") for n in design.state_names)
    doc = tomlkit.parse(src.read_text())
    doc["fdi"]["realign_noise_scale"] = 0.05
    on = tmp_path / "tanks_realigned.toml"
    on.write_text(tomlkit.dumps(doc))
    design = fdi_design(fill_missing_thresholds(load_model(on), 1e3)[0])
    ref = [n for n in design.state_names if n.startswith("parref_")]
    assert ref == ["parref_h1", "parref_h2"]
    assert len(design.init.outputs["z0"]) == len(design.state_names)
