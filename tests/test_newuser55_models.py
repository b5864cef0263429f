"""Round 55: a user's hydraulic press (pump, proportional valve, accumulator, pressures in
bar, position in mm, PI position loop), written several ways to test invariants.

The default design isolated a chamber leak 1.5-3x its test size as the valve spool: the
accumulator's Kalman filter, driven by the chamber pressure through
``Kv u sqrt(p_acc - p_A)``, predicts with its linearisation at the operating point
(2.2 V, 100 bar) and flagged at 8 V and 89 bar, inside the declared ranges. With
``[fdi] nonlinear_drivers = true`` the same log gave "leak or spool". ``inspect`` now names
the filters whose drivers enter the dynamics nonlinearly and the key that predicts
through the model.
"""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser55"


def _warnings(model):
    res = CliRunner().invoke(main, ["inspect", "--model", str(model), "--json"])
    assert res.exit_code == 0, res.output
    return [w for w in json.loads(res.stdout)["warnings"]
            if w.startswith("Kalman residuals whose drivers enter")]


def test_a_filter_reading_its_driver_through_a_nonlinearity_is_named():
    warned, = _warnings(DATA / "h0_base_T.toml")
    assert "R5 (driven by pA)" in warned and "nonlinear_drivers = true" in warned
    # predicted through the model: nothing to say
    assert not _warnings(DATA / "h0_nld.toml")
    # the cylinder's filters read their drivers linearly, or predict through f
    assert not _warnings("pneumatic_cylinder")


def test_a_valve_in_percent_detects_what_the_valve_in_volts_does():
    """The ram's position is an integrator neither pressure sees at an equilibrium; its
    computed eigenvalue (-2.5e-15 or -3.0e-15, by the last bits of the operating point)
    had moved the rank test across its tolerance, and the valve in % made both pressure
    sensors 'detectable'."""
    def detectable(path):
        res = CliRunner().invoke(main, ["inspect", "--model", str(path), "--json"])
        assert res.exit_code == 0, res.output
        return {tuple(o["outputs"]): o["detectable_continuous"]
                for o in json.loads(res.stdout)["observability"]}

    volts, percent = detectable(DATA / "h0_base.toml"), detectable(DATA / "h4a_pct.toml")
    assert volts == percent
    assert volts[("y_x",)] and not volts[("y_pA",)] and not volts[("y_acc",)]
