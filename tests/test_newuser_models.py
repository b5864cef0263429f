"""Findings of the first-time user (docs: README's model-file sections): controller laws
with parameters, plant faults without `location`, models with no residual, tune's fault
table headings. The plants are theirs (tests/data/newuser)."""

from pathlib import Path

import numpy as np
import pytest

from fdigen.errors import ModelFileError
from fdigen.model.model_file import load_model
from fdigen.sim.plant import simulate

DATA = Path(__file__).parent / "data" / "newuser"


def _variant(tmp_path, name, old, new):
    text = (DATA / name).read_text()
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new))
    return load_model(str(path))


def test_a_controller_measurement_may_use_a_parameter(tmp_path):
    """`measurement = "y2/kv"` converts the transmitter's volts back to cm with the
    model's kv (0.2 V/cm); it was refused as an undefined symbol."""
    hard = load_model(str(DATA / "twotank_cm.toml"))
    soft = _variant(tmp_path, "twotank_cm.toml", '"y2/0.2"', '"y2/kv"')
    a, b = simulate(hard, 120.0, noise=False), simulate(soft, 120.0, noise=False)
    np.testing.assert_allclose(b.u, a.u, rtol=1e-12, atol=0)
    # the loop makes h2 (cm) follow the demand in cm (15-18 cm), not 5x too low
    h2 = b.x[:, soft.state_index("h2")]
    assert np.abs(h2[-200:] - b.ref[-200:]).max() < 2.0
    assert b.ref[-200:].min() > 15.0
    with pytest.raises(ModelFileError, match=r"measurement.*'kw'"):
        _variant(tmp_path, "twotank_cm.toml", '"y2/0.2"', '"y2/kw"')


def test_a_single_target_fault_without_location_gets_it_from_its_target(tmp_path):
    """The room's faults written without `location`: the heater's term targets the input
    P (actuator), the window's the state T (plant), the thermometer's the output Tm
    (sensor): the same model as with the locations written (same hash, same faults)."""
    from fdigen.model.model_file import model_hash

    written = load_model(str(DATA / "room.toml"))
    text = (DATA / "room.toml").read_text()
    bare = text
    for loc in ("actuator", "plant", "sensor"):
        bare = bare.replace(f'location = "{loc}", ', "")
    assert "location" not in bare
    path = tmp_path / "room.toml"
    path.write_text(bare)
    inferred = load_model(str(path))
    assert {f.name: f.location for f in inferred.faults} == {
        "heater": "actuator", "window": "plant", "tsens": "sensor"}
    assert model_hash(inferred) == model_hash(written)


def test_a_model_without_residuals_is_warned_about(tmp_path):
    """The room without its parity residual: the core's only residual is the validity
    flag nf_Tm, so nothing detects anything; inspect and build say so (the isolability
    report alone said "leak2 from leak2" for the user's tanks)."""
    import json

    from click.testing import CliRunner

    from fdigen.cli import main

    text = (DATA / "room.toml").read_text()
    runner = CliRunner()
    # without it the design derives one: the whole model checked on its thermometer (the
    # structural selection's last resort, a one-state plant having no sub-model)
    derived = tmp_path / "derived.toml"
    derived.write_text(text.replace('parity = {R1 = "Tm"}\n', ""))
    res = runner.invoke(main, ["inspect", "--model", str(derived), "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert set(info["signature_table"]) == {"R1", "nf_Tm"}
    assert not any("any fault" in w for w in info["warnings"])
    # and with the derived residuals switched off, nothing is left but the validity flag
    path = tmp_path / "noresid.toml"
    path.write_text(text.replace('parity = {R1 = "Tm"}\n', "extra_residuals = false\n"))
    assert "parity" not in path.read_text()
    res = runner.invoke(main, ["inspect", "--model", str(path), "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert set(info["signature_table"]) == {"nf_Tm"}
    assert [w.startswith("no residual can detect any fault") for w in info["warnings"]] == [True]
    res = runner.invoke(main, ["build", "--model", str(path), "--out", str(tmp_path / "gen")])
    assert res.exit_code == 0, res.output
    assert "warning: no residual can detect any fault" in res.output
    assert "declare [fdi.parity] or [fdi.kalman]" in res.output
    # with its residual, the model is not warned about as a whole
    res = runner.invoke(main, ["inspect", "--model", str(DATA / "room.toml"), "--json"])
    assert res.exit_code == 0, res.output
    assert not any("any fault" in w for w in json.loads(res.output)["warnings"])


def test_pi_is_the_constant_in_equations(tmp_path):
    """`pi` in an equation (a round tank's area, `pi*r^2`) was refused as an undefined
    symbol while the README's [simulation] references use it: it is the constant, and the
    model means what the same model with the number means (no model can declare a `pi`)."""
    import math

    num = _variant(tmp_path, "twotank_cm.toml", 'h1 = "(qp - q12)/A1"',
                   f'h1 = "(qp - q12)/(A1*{math.pi!r}/3.141592653589793)"')
    sym = _variant(tmp_path, "twotank_cm.toml", 'h1 = "(qp - q12)/A1"',
                   'h1 = "(qp - q12)/(A1*pi/3.141592653589793)"')
    assert sym.f() == num.f()
    a, b = simulate(num, 60.0, seed=2), simulate(sym, 60.0, seed=2)
    np.testing.assert_array_equal(a.y, b.y)
    path = tmp_path / "own_pi.toml"
    path.write_text((tmp_path / "twotank_cm.toml").read_text().replace(
        "A1  = {", 'pi = { value = 3.0, unit = "1", description = "not the constant" }\nA1  = {'))
    with pytest.raises(ModelFileError, match="reserves"):     # no name can shadow it
        load_model(str(path))


def test_inspect_names_what_a_definitions_fault_enters_and_second_sensors():
    """A clogging written inside [definitions] (`q12 = (1 - clog)*c12*sqrt(...)`, the
    fault declares no target): inspect named no equation ("fault clog enters  (one
    fault)"); it enters h1 and h2, as one signal their combination cancels."""
    from click.testing import CliRunner

    from fdigen.cli import main

    res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / "tanks_cm_guarded.toml")])
    assert res.exit_code == 0, res.output[-1500:]
    assert "fault clog enters h1, h2 (one fault)" in res.output
    # the clogging is one signal the two balances share: their combination is blind to
    # it, derived (inspect had advised a second sensor on h1 instead)
    assert "combination" in res.output and "blind to clog" in res.output
    assert "a sensor on h1" not in res.output


def test_output_error_simulation_is_accurate_not_only_stable():
    """The user's geared motor at 10 ms: its electrical mode (Ra/La = 400 1/s) ran at a
    fixed 2 RK4 sub-steps (|lambda h| = 2: stable, 2.5x off the mode's decay per step) in
    discover's output-error model, and on a healthy log a dead band 'explained' that
    discretisation error. The sub-steps now keep |lambda h| <= 0.5: the output-error
    simulation follows fdigen's plant simulator to 1e-5 of each output's span (it was 1e-2
    on the current)."""
    from fdigen.discover.output_error import accurate_substeps, build_model
    from fdigen.discover.output_error import simulate as free_run

    model = load_model(str(DATA / "motor_gear_rpm.toml"))
    sim = simulate(model, 3.0, noise=False, seed=0)
    dt = float(np.median(np.diff(sim.t)))
    n = accurate_substeps(model, dt)
    values = {q.name: float(q.value) for q in model.parameters}
    err = {}
    for sub in (2, n):
        _, Y = free_run(build_model(model, [], dt, sub), sim.x[0], sim.u, values)
        err[sub] = (np.abs(Y - sim.y).max(axis=0) / np.ptp(sim.y, axis=0)).max()
    assert err[n] < 1e-5 < 1e-3 < err[2]


def test_discover_method_output_error_on_a_healthy_log(tmp_path):
    """`discover --method output-error` runs the output-error loop on a log the equation
    test could read (the user's motor, tachometer in volts: measured through its map), and
    on a healthy log of the model's own plant it adds nothing (it added a 'confirmed' dead
    band before the sub-steps were made accurate)."""
    from click.testing import CliRunner

    from fdigen.cli import main
    from fdigen.sim.log import write_log

    model = load_model(str(DATA / "motor_gear_rpm.toml"))
    sim = simulate(model, 4.0, seed=3)
    log = tmp_path / "healthy.csv"
    write_log(log, sim.columns())
    res = CliRunner().invoke(main, ["discover", str(log), "--model",
                                    str(DATA / "motor_gear_rpm.toml"), "--method",
                                    "output-error", "--out", str(tmp_path / "d"), "--no-build",
                                    "--no-fdi", "--json"])
    assert res.exit_code == 0, res.output[-1500:]
    import json

    out = json.loads(res.stdout)
    assert out["method"] == "output_error" and out["reason"] == "--method output-error"
    assert out["effects"] == []


def test_a_state_dependent_balance_separates_what_the_structure_allows():
    """A user's HVAC zone: the damper's mass flow enters the zone-temperature and CO2
    balances in a ratio of those states, so no residual was blind to it and four pairs the
    structure allows stayed unseparated (inspect then said why). The balance that cancels
    it, ``(CO2 - CO2_out) / (T_z - T_out)^(Cap_z/(rho V cp))`` (a first integral of the
    fault's direction, :mod:`fdigen.design.first_integral`), is now a residual: every pair
    the structure and the equations allow is achieved. Where that power is not real over
    the declared range of ``T_z`` (an outdoor temperature inside it) the refusal says so."""
    import dataclasses
    import json

    from click.testing import CliRunner

    from fdigen.cli import main
    from fdigen.design.decoupling import decoupling_refusal
    from fdigen.model.model_file import load_model

    res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / "hvac_zone.toml"),
                                    "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    iso = info["isolability"]
    assert iso["achievable_not_achieved"] == [] and iso["not_achieved_reasons"] == {}
    blind = [r for r in info["extra_residuals"] if r["blind_to"] == "damper"]
    assert blind and set(blind[0]["drivers"]) == {"T_z", "CO2"}
    # the window, written as terms on the same two balances, is one fault signal as the
    # damper's flow is: the same residual is blind to it too
    assert info["signature_table"][blind[0]["residual"]]["window"] == 0
    assert info["signature_table"][blind[0]["residual"]]["coil"] == 1
    model = load_model(str(DATA / "hvac_zone.toml"))
    warm = dataclasses.replace(model, parameters=tuple(
        dataclasses.replace(p, value=20.0) if p.name == "T_out" else p
        for p in model.parameters))
    why = decoupling_refusal(warm, warm.fault("damper"))
    assert "depends on those states" in why and "not real over their declared ranges" in why
    for name in ("pneumatic_cylinder", "three_tank"):
        res = CliRunner().invoke(main, ["inspect", "--model", name, "--json"])
        assert json.loads(res.output)["isolability"]["not_achieved_reasons"] == {}


def test_a_fault_only_a_structural_residual_sees_is_acted_on():
    """A user's two tanks declare no residual; fdigen derives R1 (class-isolating) and R2
    (structural, fault-level: kept out of the class decision). The leak and the pump loss
    are in R2's signature alone, so they were detected and never reached the class
    decision: no class, no action, on a leak whose class calls for safety_stop. R2 now
    decides classes too (only because some fault has nothing else), and a simulated leak
    is acted on."""
    import numpy as np

    from fdigen.backends.c import CFdi
    from fdigen.design.cache import cached_design
    from fdigen.sim.plant import FaultEvent

    design = cached_design(load_model(str(DATA / "two_tank_derived_only.toml")))
    ev = design.evaluation
    table = design.signature_table
    # R3, the whole model checked on y1, is the structural selection's last resort (it
    # tells the level sensor from the leak): structural too, and deciding classes too
    assert {r for r in table["leak1"] if not r.startswith("nf_")} == {"R2", "R3"}
    assert ev.class_flags >> ev.residuals.index("R2") & 1
    assert ev.class_flags >> ev.residuals.index("R3") & 1
    leak = design.model.fault("leak1")
    sim = simulate(design.model, 600.0, seed=2,
                   faults=(FaultEvent("leak1", 300.0, 4 * leak.test_size),))
    out = CFdi(design).run(sim.u, sim.y)
    flags, action = np.asarray(out["flags"]), np.asarray(out["action"])
    k = np.flatnonzero(flags)
    assert k.size and sim.t[k[0]] >= 300.0
    assert action[-1] == 2                       # safety_stop: every consistent class's
    # the structural residuals of the shipped cylinder stay fault-level (each of its faults
    # has class-level residuals)
    from fdigen.model.model_file import builtin_model_path

    cyl = cached_design(load_model(builtin_model_path("pneumatic_cylinder")))
    for name in ("R8", "R9"):
        assert not cyl.evaluation.class_flags >> cyl.evaluation.residuals.index(name) & 1


def test_a_derived_filter_is_named_as_derived_in_messages():
    """A stability refusal told a user about `fdi.kalman.R1`, a table they never wrote:
    a derived filter is named as what it is."""
    from fdigen.design.cache import cached_design
    from fdigen.design.observers import filter_label
    from fdigen.model.model_file import builtin_model_path

    tanks = cached_design(load_model(builtin_model_path("three_tank")))
    r4 = next(k for k in tanks.kalman if k.residual == "R4")
    assert filter_label(tanks.model, r4) == ("derived residual R4 (Kalman filter of the "
                                             "equations of h2 driven by h1<-y1, h3<-y3)")
    cyl = cached_design(load_model(builtin_model_path("pneumatic_cylinder")))
    r4 = next(k for k in cyl.kalman if k.residual == "R4")
    assert filter_label(cyl.model, r4) == "fdi.kalman.R4"
