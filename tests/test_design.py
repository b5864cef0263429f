"""The FDI design: signature table (paper Table 1), voter, RMS, reference step, rig logs."""

import json
import re

import numpy as np
import pytest
import scipy.integrate
import sympy as sp
from click.testing import CliRunner

from fdigen.backends.reference import ReferenceFdi, lambdify_program
from fdigen.cli import main
from conftest import read_rig_log

# Table 1 of the paper, columns as declared faults of the built-in model.
# (The paper's x1 column is a fault of the Kalman estimate, not a physical fault.)
PAPER_TABLE_1 = {
    "valve": {"R1", "R2", "R3", "R4", "R5"},
    "leak_p": {"R1", "R2", "R3", "R4", "R5"},
    "blockage_p": {"R1", "R2", "R3", "R4", "R5"},
    "position_sensor": {"R1", "R4", "w3"},           # x3, the primary sensor
    "redundant_position_sensor": {"R1", "R4", "w2"},  # x2
    "pressure_sensor_p": {"R2", "R5"},
    "pressure_sensor_n": {"R3", "R5"},
}
# Where the derived table differs, and why (also in the README):
#  - a redundant-sensor fault cannot move R1 (eq 8 uses the primary sensor only) nor R4
#    (its filter is updated with the voter's fused measurement, which votes x2 out).
DOCUMENTED_DIFFERENCES = {("redundant_position_sensor", "R1"), ("redundant_position_sensor", "R4")}


def test_signature_table_reproduces_table_1(cylinder_design):
    table = cylinder_design.signature_table
    paper = set(cylinder_design.paper_residuals)
    for fault, expected in PAPER_TABLE_1.items():
        derived = table[fault] & paper
        diff = (derived ^ expected)
        assert {(fault, r) for r in diff} <= DOCUMENTED_DIFFERENCES, (fault, derived, expected)


def test_derived_residuals_make_classes_isolable(cylinder_design):
    d = cylinder_design
    extras = {e["residual"]: e for e in d.extra_residuals}
    # the force balance driven by the measured pressures separates pressure-sensor faults
    force = [e for e in extras.values() if e["equations"] == ["x", "xdot"]]
    assert force and force[0]["drivers"] == {"Pp": "pp", "Pn": "pn"}
    # the valve-blind combination Vp*pp + Vn*pn separates actuator from leak/blockage
    blind = [e for e in extras.values() if e["blind_to"] == "valve"]
    assert blind, extras
    r = blind[0]["residual"]
    t = d.signature_table
    assert r not in t["valve"] and r in t["leak_p"] and r in t["leak_n"]
    assert r in t["blockage_p"]
    assert d.unresolved_across_classes == ()
    # leak and blockage in the same line enter the same equation: not separable
    assert ("leak_p", "blockage_p") in d.unresolved_within_class


def test_decoupling_finds_the_volume_weights(cylinder):
    from fdigen.design.decoupling import decoupling_direction
    idx, m = decoupling_direction(cylinder, cylinder.fault("valve"))
    A, x, V0, L = sp.symbols("A x V0 L", real=True)
    assert idx == [0, 1]
    pp, pn = (cylinder.states[i].symbol for i in idx)
    c = [sp.diff(m, pp), sp.diff(m, pn)]      # the weights of the two pressures
    ratio = sp.simplify(c[1] / c[0] - (V0 + A * (L - x)) / (V0 + A * x))
    assert ratio == 0


def _voter_eval(design, x1, x2, x3):
    """Evaluate only the voter assignments of the step program."""
    prog = design.step
    subs = {}
    names = {}
    for sym, expr in prog.assignments:
        names[sym.name] = sym
    y = {o.name: o.symbol for o in design.model.outputs}
    vals = {y["x2"]: x2, y["x3"]: x3, names["yhat_R4"]: x1}
    for sym, expr in prog.assignments:
        if sym.name.startswith(("vd", "vw", "voter", "r_w")):
            vals[sym] = float(expr.xreplace(vals))
    return {s.name: v for s, v in vals.items() if isinstance(s, sp.Symbol)}


@pytest.mark.parametrize("x1,x2,x3", [(0.1, 0.1001, 0.0999), (0.1, 0.1002, 0.0), (0.1, 0.05, 0.1),
                                      (0.08, 0.1, 0.1), (0.1, 0.1, 0.1)])
def test_voter_is_broens_with_corrected_w1(cylinder_design, x1, x2, x3):
    a = cylinder_design.config.voter.tolerance
    w1 = 1 / (1 + ((x1 - x2) / a) ** 2 * ((x1 - x3) / a) ** 2)   # eq 19 corrected
    w2 = 1 / (1 + ((x2 - x1) / a) ** 2 * ((x2 - x3) / a) ** 2)   # eq 20
    w3 = 1 / (1 + ((x3 - x1) / a) ** 2 * ((x3 - x2) / a) ** 2)   # eq 21
    s = w1 + w2 + w3
    got = _voter_eval(cylinder_design, x1, x2, x3)
    assert got["voter_out"] == pytest.approx((w1 * x1 + w2 * x2 + w3 * x3) / s, rel=1e-12)
    for j, w in enumerate((w1, w2, w3), start=1):
        assert got[f"r_w{j}"] == pytest.approx(max(1 - 3 * w / s, 0.0), abs=1e-12)


def test_moving_rms_matches_window_sum(cylinder_design):
    ref = ReferenceFdi(cylinder_design)
    rng = np.random.default_rng(3)
    n_res = len(cylinder_design.residual_names)
    N = cylinder_design.evaluation.window
    r = rng.standard_normal((3 * N + 17, n_res)) * np.logspace(-5, 3, n_res)
    rms = np.array([ref.evaluate(row) for row in r])
    sq = np.vstack([np.zeros((N - 1, n_res)), r ** 2])
    window = np.array([sq[k:k + N].sum(axis=0) for k in range(r.shape[0])])
    np.testing.assert_allclose(rms, np.sqrt(window / N), rtol=1e-9)


def test_parity_model_follows_an_exact_plant(cylinder, cylinder_design):
    """Noise-free plant integrated by SciPy (tight tolerance, held input): the parity
    residuals are the RK4 discretisation error only."""
    model = cylinder
    f = sp.lambdify([list(model.x), list(model.u)], list(model.f().xreplace(
        {k: sp.Float(v) for k, v in model.parameter_values.items()})))
    dt = cylinder_design.config.sample_time
    K = 2000
    t = np.arange(K) * dt
    u = (0.8 * np.sin(2 * np.pi * 1.3 * t) + 0.3 * np.sin(2 * np.pi * 3.1 * t))[:, None]
    x = np.array([3.5e5, 3.5e5, 0.1, 0.0])
    xs = [x]
    for k in range(K - 1):
        sol = scipy.integrate.solve_ivp(lambda _t, s: f(list(s), [u[k, 0]]), (0, dt), xs[-1],
                                        rtol=1e-12, atol=[1e-6, 1e-6, 1e-13, 1e-12])
        xs.append(sol.y[:, -1])
    xs = np.array(xs)
    y = np.stack([xs[:, 2], xs[:, 2], xs[:, 0], xs[:, 1]], axis=1)
    ref = ReferenceFdi(cylinder_design)
    ref.initialise(u[0], y[0])
    zi = ref.z.copy()
    zi[cylinder_design.state_names.index("par_xdot")] = 0.0
    ref.z = zi
    worst = np.zeros(3)
    for k in range(K):
        ref.z, r, _ = ref.core(ref.z, u[k], y[k], (1.0, 0.0))
        worst = np.maximum(worst, np.abs(r[:3]))
    assert worst[0] < 1e-7, worst      # position [m]
    assert worst[1] < 1.0 and worst[2] < 1.0, worst  # pressures [Pa], vs 3.5e5


RIG_CASES = {
    "fdi_healthy": ("none", "none"),
    "fdi_actuator_loss": ("pneumatic_or_actuator", "safety_stop"),
    "fdi_blockage_p": ("pneumatic_or_actuator", "safety_stop"),
    "fdi_leak_p": ("pneumatic_or_actuator", "safety_stop"),
    "fdi_position_sensor_loss": ("position_sensor", "accommodate"),
    "fdi_pressure_n_drift": ("pressure_sensor_n", "none"),
    "fdi_pressure_p_loss": ("pressure_sensor_p", "none"),
}


@pytest.mark.parametrize("case", sorted(RIG_CASES))
def test_classifies_rig_logs(cylinder_design, case):
    """On the compiled core (proven equal to the reference in test_verify)."""
    from fdigen.backends.c.loader import CFdi
    t, u, y = read_rig_log(case)
    truth = json.loads((read_rig_log.__globals__["RIG"] / "logs" / f"{case}.json").read_text())
    out = CFdi(cylinder_design).run(u, y)
    ev = cylinder_design.evaluation
    cls, act = RIG_CASES[case]
    assert ev.classes[out["fault_class"][-1]] == cls
    assert ev.actions[out["fault_class"][-1]] == act
    faults = truth["truth"]["faults"]
    if not faults:
        assert out["flags"][-1] == 0
    else:
        k_iso = int(np.argmax(out["fault_class"] > 0))
        assert t[k_iso] > faults[0]["t0"]      # never before the fault
        # flags raised at isolation are consistent with this class's signatures only
        mask = int(out["flags"][k_iso])
        raised = {r for i, r in enumerate(ev.residuals) if mask >> i & 1}
        consistent = {cylinder_design.model.fault(f).fault_class
                      for f, s in cylinder_design.signature_table.items() if raised <= s}
        assert consistent == {cls}


def test_actuator_loss_does_not_raise_the_valve_blind_residual(cylinder_design):
    t, u, y = read_rig_log("fdi_actuator_loss")
    blind = [e["residual"] for e in cylinder_design.extra_residuals if e["blind_to"] == "valve"][0]
    i = cylinder_design.residual_names.index(blind)
    from fdigen.backends.c.loader import CFdi
    out = CFdi(cylinder_design).run(u, y)
    assert not (out["flags"][-1] >> i) & 1
    t, u, y = read_rig_log("fdi_leak_p")
    out = CFdi(cylinder_design).run(u, y)
    assert (out["flags"][-1] >> i) & 1


def test_second_model_gets_its_own_design(motor_design):
    d = motor_design
    assert d.residual_names[:4] == ("Rw", "Ri", "Kw", "Ki")
    t = d.signature_table
    assert t["tach"] >= {"Rw", "Kw"} and "Ri" not in t["tach"]
    assert t["current_sensor"] >= {"Ri", "Ki"} and "Rw" not in t["current_sensor"]
    # a derived residual driven by the measured current separates load and drive faults
    extra = {e["residual"]: e for e in d.extra_residuals}
    assert extra
    assert d.unresolved_across_classes == () or all(
        {d.model.fault(a).fault_class, d.model.fault(b).fault_class} == {"drive", "electrical"}
        for a, b in d.unresolved_across_classes)


def test_inspect_json(cylinder_design):
    res = CliRunner().invoke(main, ["inspect", "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    r4 = [k for k in info["kalman"] if k["residual"] == "R4"][0]
    assert r4["coordinates"] == ["Pd", "x", "xdot"]
    assert np.allclose(r4["T"], [[1, -1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    ours = [k for k in cylinder_design.kalman if k.residual == "R4"][0]
    np.testing.assert_allclose(r4["gain_discrete_filter_M"], ours.gain.M)
    assert set(info["signature_table"]) == set(cylinder_design.residual_names)
    assert info["signature_table"]["w3"]["position_sensor"] == 1
    assert len(info["linearisation"]["A"]) == 4


def test_bad_model_file_is_a_clean_cli_error(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[model]\nname = "m"\n[parameters]\n[states]\nx = {}\n[inputs]\nu = {}\n'
                   '[dynamics]\nx = "__import__(\'os\')"\n[outputs]\ny = {expr = "x"}\n'
                   '[operating_point]\nx = 0\nu = 0\n')
    res = CliRunner().invoke(main, ["inspect", "--model", str(bad)])
    assert res.exit_code == 2
    assert "bad.toml" in res.output and "dynamics.x" in res.output
    assert "Traceback" not in res.output


@pytest.mark.parametrize("old,new,match", [
    ('measurement = "pp - pn"', 'measurement = "pp - pp"', "nothing is observable"),
    ('R1 = "x3"\nR2 = "pp"\nR3 = "pn"', 'R2 = "pp"', "not detectable"),
    ('R4 = 5.8e-5', 'R4 = -1.0', "thresholds.R4"),
    ('sample_time = 1e-3', 'sample_time = -1e-3', "fdi.sample_time"),
    ('Pp = 3.0e3', 'Pp = -3.0e3', "process_noise"),
])
def test_impossible_designs_are_clean_errors(tmp_path, old, new, match):
    from fdigen.model.model_file import builtin_model_path
    text = builtin_model_path().read_text()
    assert old in text
    path = tmp_path / "m.toml"
    path.write_text(text.replace(old, new, 1))
    res = CliRunner().invoke(main, ["inspect", "--model", str(path)])
    assert res.exit_code == 2, res.output
    assert match in res.output and "Traceback" not in res.output


def test_inspect_lists_rank_per_output_set():
    res = CliRunner().invoke(main, ["inspect", "--json"])
    obs = {tuple(o["outputs"]): o for o in json.loads(res.output)["observability"]}
    assert obs[("x3",)]["rank"] == 3 and not obs[("x3",)]["detectable_continuous"]
    assert obs[("pp", "pn")]["rank"] == 3          # the position is not seen by pressures
    assert obs[("x3", "pp")]["observable"]
    assert len(obs) == 15


def test_stiff_parallel_model_is_refused_with_the_substeps_that_would_work():
    """A 10 g piston: the chamber-stiffness mode (about -1.6e4 1/s here) is outside RK4's
    stability region at 1 ms; the design names the mode and the sub-steps needed, and
    builds with them. The number asked for is checked against RK4's amplification."""
    from fdigen.design.parallel_model import check_parallel_model_step, rk4_amplification
    from fdigen.design.config import read_fdi_config
    from fdigen.derive.linearisation import linearise
    from fdigen.errors import DesignError
    from fdigen.model.model_file import builtin_model_path, parse_model_text

    text = builtin_model_path("pneumatic_cylinder").read_text()
    # (the shipped bounds exclude such a mass: widen them for this design-level check)
    stiff = text.replace('M     = { value = 3.0,', 'M     = { value = 0.01,').replace(
        'bounds = [0.956, 12.4]', 'bounds = [0.01, 1000.0]')
    assert stiff != text
    model = parse_model_text(stiff, source="stiff.toml")
    with pytest.raises(DesignError, match=r"stiff.toml: fdi.substeps: the RK4 parallel model "
                                          r"is unstable.*use substeps >= (\d+)") as info:
        check_parallel_model_step(model, read_fdi_config(model))
    need = int(info.value.args[0].rsplit(">= ", 1)[1].split()[0])
    lam = np.linalg.eigvals(linearise(model).A)
    assert max(abs(rk4_amplification(lam * 1e-3))) > 1            # really unstable at 1 ms
    assert max(abs(rk4_amplification(lam * 1e-3 / need))) <= 1 + 1e-9
    assert max(abs(rk4_amplification(lam * 1e-3 / (need - 1)))) > 1  # and the least that works
    fixed = parse_model_text(stiff.replace("substeps = 1 ", f"substeps = {need} "),
                             source="stiff.toml")
    check_parallel_model_step(fixed, read_fdi_config(fixed))     # no error


def test_scheduled_filter_unstable_on_its_schedule_is_refused():
    """A 0.1 cm^3 dead volume: at full extension the chamber is so stiff that the
    scheduled position filter's frozen error dynamics are unstable at 1 ms; the design says
    where and what to do, and the same model with a fixed prediction designs."""
    from fdigen.design.fdi_design import fdi_design
    from fdigen.errors import DesignError
    from fdigen.model.model_file import builtin_model_path, parse_model_text

    text = builtin_model_path("pneumatic_cylinder").read_text()
    tiny = text.replace('value = 1.0e-5, unit = "m^3"', 'value = 1.0e-7, unit = "m^3"').replace(
        'bounds = [3.28e-06, 0.01]', 'bounds = [1e-8, 0.01]')     # outside the shipped bounds
    assert tiny != text
    with pytest.raises(DesignError, match=r"tiny.toml: fdi.kalman.R4.schedule: the scheduled "
                                          r"prediction is unstable at x = 0.2 .*spectral "
                                          r"radius .* >= 1.*schedule = \"operating_point\""):
        fdi_design(parse_model_text(tiny, source="tiny.toml"))
    fixed = tiny.replace('schedule = "measured"', 'schedule = "operating_point"')
    design = fdi_design(parse_model_text(fixed, source="tiny.toml"))
    assert all(k.schedule == "operating_point" for k in design.kalman)


def test_scheduled_filters_read_only_the_voter_and_their_own_sensors(cylinder_design):
    """R4 (position, updated by the voter) follows the voted position only; R5 (pressure
    difference) the measured pressures it reads and the voted position; the derived R6 is
    not scheduled. So scheduling adds no sensor fault to a filter's signature: the
    structural signature table of the scheduled design equals the unscheduled one."""
    from fdigen.design.describe import describe_design
    from fdigen.design.fdi_design import fdi_design
    from fdigen.model.model_file import parse_model_text

    kal = {k["residual"]: k for k in describe_design(cylinder_design)["kalman"]}
    assert kal["R4"]["schedule"] == kal["R5"]["schedule"] == "measured"
    def reads(k):       # min(hi, max(lo, signal)) -> signal
        return {s: re.fullmatch(r"min\(\w+, max\([\w.]+, (\w+)\)\)", sig).group(1)
                for s, sig in kal[k]["scheduled_on"].items()}

    assert reads("R4") == {"x": "voter_out"}
    assert reads("R5") == {"Pp": "pp", "Pn": "pn", "x": "voter_out"}
    assert kal["R6"]["scheduled_on"] == {}
    from fdigen.model.model_file import builtin_model_path

    design = cylinder_design
    text = builtin_model_path("pneumatic_cylinder").read_text()
    fixed = fdi_design(parse_model_text(
        text.replace('schedule = "measured"', 'schedule = "operating_point"')))
    assert fixed.signature_table == design.signature_table
