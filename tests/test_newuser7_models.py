"""Plants a first-time user wrote from the README alone (newuser7, 2026-11-27).

``maglev_open_loop.toml``: a magnetic levitation rig, unstable open loop, its parity
residuals' parallel models without realignment (the README's default). They diverge:
``tune`` ended in "cannot write threshold inf" (no residual named), and ``verify`` failed
with "max rel inf" although every backend agreed bit for bit (inf - inf read as a
difference).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "newuser7"
MAGLEV = DATA / "maglev_open_loop.toml"


def test_inspect_warns_of_open_loop_parallel_models_on_an_unstable_plant():
    res = CliRunner().invoke(main, ["inspect", "--model", str(MAGLEV)])
    assert res.exit_code == 0, res.output
    assert "unstable open loop at the operating point" in res.output
    assert "realign_noise_scale" in res.output


def test_tune_names_the_residuals_without_a_finite_healthy_rms(tmp_path):
    path = tmp_path / "m.toml"
    path.write_text(MAGLEV.read_text())
    res = CliRunner().invoke(main, ["tune", "--model", str(path), "--runs", "6",
                                    "--validation-runs", "1", "--fault-sizes", "1",
                                    "--fault-starts", "1", "--horizon-runs", "0"])
    assert res.exit_code == 2, res.output
    assert "healthy RMS of Rgap" in res.stderr and "not finite" in res.stderr
    assert "threshold inf" not in res.stderr


def test_equal_infinities_are_no_difference():
    from fdigen.verify.equivalence import _compare

    got = np.array([[np.inf, 1.0], [np.nan, 2.0], [-np.inf, 3.0]])
    d = _compare("c", "trajectory", ["a", "b"], got, got.copy())
    assert [x.max_rel for x in d] == [0.0, 0.0] and [x.max_abs for x in d] == [0.0, 0.0]
    other = got.copy()
    other[0, 0] = 5.0
    assert _compare("c", "trajectory", ["a", "b"], got, other)[0].max_rel == np.inf
