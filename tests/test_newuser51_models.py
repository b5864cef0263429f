"""Round 51: plants written from the README alone (tests/data/newuser51): a magnetic
levitation rig, a CSTR with a hidden concentration, a pump feeding an elevated tank."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser51"


def _pump_spellings(tmp_path):
    from fdigen.model.model_file import load_model

    text = (DATA / "pump.toml").read_text()
    assert 'Cv*sqrt(max(h, 0))' in text
    bare = tmp_path / "pump_unguarded.toml"
    bare.write_text(text.replace("Cv*sqrt(max(h, 0))", "Cv*sqrt(h)"))
    return load_model(DATA / "pump.toml"), load_model(bare)


def test_a_guard_that_never_acts_derives_what_the_bare_root_does(tmp_path):
    """``sqrt(max(h, 0))`` on a level of 0.5-1.5 m (the README's advice) was linearised by
    a describing function over the range: the tank's A was -0.513 Cv/At against the bare
    root's exact -0.5 Cv/At, its level filter switched to the nonlinear prediction, and
    the two spellings tuned different thresholds. The same design now, the same
    simulation and the same residuals."""
    from fdigen.backends.reference import ReferenceFdi
    from fdigen.derive.linearisation import linearise
    from fdigen.design.fdi_design import fdi_design
    from fdigen.sim.plant import FaultEvent, simulate

    guarded, bare = _pump_spellings(tmp_path)
    np.testing.assert_allclose(linearise(guarded).A, linearise(bare).A, rtol=1e-14, atol=0)
    dg, db = fdi_design(guarded), fdi_design(bare)
    assert dg.residual_names == db.residual_names
    assert dg.config.kalman == db.config.kalman
    assert [k.schedule for k in dg.kalman] == [k.schedule for k in db.kalman]
    fault = (FaultEvent("leak", 300.0, 6e-4),)
    sg, sb = (simulate(m, 900.0, faults=fault, seed=4) for m in (guarded, bare))
    np.testing.assert_array_equal(sg.y, sb.y)
    rg, rb = ReferenceFdi(dg).run(sg.u, sg.y), ReferenceFdi(db).run(sb.u, sb.y)
    np.testing.assert_allclose(np.asarray(rg["r"]), np.asarray(rb["r"]), rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_array_equal(np.asarray(rg["flags"]), np.asarray(rb["flags"]))


def test_a_switch_that_acts_in_the_range_keeps_its_describing_function():
    """The settled-switch rule leaves a real switch alone: a dead band across the range
    keeps the describing-function gain."""
    import sympy as sp

    from fdigen.derive.linearisation import _settled_switch

    v = sp.Symbol("v", real=True)
    assert _settled_switch(sp.Max(v, 0), {v: (0.5, 1.5)}, {})
    assert not _settled_switch(sp.Max(v, 0), {v: (-0.5, 1.5)}, {})
    assert not _settled_switch(sp.Max(v, 0), {v: (0.0, 1.5)}, {})     # touches the kink
    assert _settled_switch(sp.Abs(v - 3), {v: (0.5, 1.5)}, {})
    assert not _settled_switch(sp.sign(v - 1), {v: (0.5, 1.5)}, {})


def test_a_kalman_filter_on_a_noise_free_sensor_names_the_sensor():
    """``noise_std = 0`` on a sensor a Kalman filter reads: "measurement noise weight R
    must be positive definite", naming no file and no field."""
    res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / "cstr_noise_zero.toml")])
    assert res.exit_code == 2, res.output
    assert "field 'outputs.yT.noise_std'" in res.output
    assert "cstr_noise_zero.toml" in res.output


def test_a_zero_test_size_is_refused_where_the_file_is_read(tmp_path):
    text = (DATA / "cstr_orig.toml").read_text()
    assert "test_size = 0.2" in text
    bad = tmp_path / "cstr.toml"
    bad.write_text(text.replace("test_size = 0.2", "test_size = 0", 1))
    res = CliRunner().invoke(main, ["inspect", "--model", str(bad)])
    assert res.exit_code == 2, res.output
    assert "test_size = 0 is no fault" in res.output and ".test_size'" in res.output


def test_a_residual_growing_through_the_healthy_runs_is_named():
    """The reactor's balance R3 peaked at the last sample of all 16 healthy runs of
    1800 s; run for 7200 s inside the tolerance it crossed its threshold at 3075 s."""
    from fdigen.tune.run_notes import growing_residuals, growing_text

    def run(t_r3, t_rt):
        return {"max_rms": {"R3": 2.0, "RT": 1.0}, "t_max": {"R3": t_r3, "RT": t_rt}}

    healthy = [run(1799.0, 300.0), run(1799.0, 1790.0), run(1720.0, 600.0),
               run(900.0, 1000.0)]
    grow = growing_residuals(healthy, ["R3", "RT"], 1800.0)
    assert grow == {"R3": {"runs": 3, "of": 4}}
    assert "R3 (in 3 of 4 healthy runs)" in growing_text(grow, 1800.0)
