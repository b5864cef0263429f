"""Regressions of the third attack round (a reviewer with the code, on the features added
for users' plants: a parameter's own tolerance, faults inside equations, static relations,
the domain check of simulate, sample times up to an hour). Files in tests/data/attack3.

* a commissioned file with ``tolerance = 3.55`` (an offset calibrated near 0) was written
  and then refused by every command;
* tune wrote a threshold set by healthy runs that had left the equations' domain (R1 =
  6.09; the valid runs at most 0.68), and a horizon of 0 s the file then refused;
* more than 31 residuals, a constant beyond a C float, a duration of 1e12 s: internal
  errors (exit 3) or a MemoryError;
* an output that reads an input only aborted the design ("nothing is observable").
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "attack3"


def test_a_spread_wider_than_the_value_is_capped_and_never_written_unreadable(tmp_path):
    from fdigen.commission.pipeline import commissioned_text
    from fdigen.commission.spread import MAX_TOLERANCE, campaign_tolerances, wide_intervals
    from fdigen.errors import FdigenError
    from fdigen.files.model_write import write_model_text
    from fdigen.model.model_file import parse_model_text

    params, std = {"uoff": -0.0868, "kp": 4.07}, {"uoff": 0.1026, "kp": 0.031}
    per = campaign_tolerances(params, std, 3.0, 0.05)
    assert per == {"uoff": MAX_TOLERANCE, "kp": 0.05}
    (warning,) = wide_intervals(params, std, 3.0)
    assert warning.startswith("uoff calibrated to -0.0868") and "+-355 %" in warning
    text = (DATA / "dom2.toml").read_text()
    capped = commissioned_text(text, [], {}, {}, "log.csv", "test", tolerances={"hb": 0.9})
    assert parse_model_text(capped, source="c.toml")
    bad = capped.replace("tolerance = 0.9", "tolerance = 3.55")
    assert bad != capped
    target = tmp_path / "m.toml"
    with pytest.raises(FdigenError, match="does not read back"):
        write_model_text(target, bad)
    assert not target.exists()


def test_tune_designs_from_the_runs_that_stay_in_the_domain(tmp_path):
    model = tmp_path / "dom2.toml"
    model.write_text((DATA / "dom2.toml").read_text())
    args = ["tune", "--model", str(model), "--runs", "10", "--validation-runs", "0",
            "--fault-sizes", "1", "--fault-starts", "1", "--no-realign-search"]
    res = CliRunner().invoke(main, args + ["--json"])
    assert res.exit_code == 0, res.output[-2000:]
    rep = json.loads(res.stdout)
    gone = {r["index"] for r in rep["left_domain"] if r["kind"] == "healthy"}
    assert gone                                   # hb spread +-90 %: some runs start outside
    kept = [r for r in rep["runs"]["healthy"] if r["index"] not in gone]
    worst_kept = max(r["max_rms"]["R1"] for r in kept)
    worst_gone = max(r["max_rms"]["R1"] for r in rep["runs"]["healthy"] if r["index"] in gone)
    assert worst_gone > 2 * worst_kept            # the runs that would have set it
    # the healthy plant at the tolerance box's vertices (those in the domain) sets a floor
    vertex = rep["threshold_statistics"]["residuals"]["R1"]["vertex_max"]
    assert rep["thresholds"]["R1"] < worst_gone
    assert rep["thresholds"]["R1"] < 2 * max(worst_kept, vertex)
    # and what --write writes reads back
    assert CliRunner().invoke(main, args + ["--write"]).exit_code == 0
    assert CliRunner().invoke(main, ["inspect", "--model", str(model)]).exit_code == 0


@pytest.mark.parametrize("args,message", [
    (["build", "--model", str(DATA / "m30.toml")], "the flag word holds 31"),
    (["build", "--model", str(DATA / "dom40.toml")], "beyond the range of a C float"),
    (["simulate", "--model", str(DATA / "room.toml"), "--duration", "1e12"],
     "samples: at most 1e+07"),
])
def test_limits_are_errors_that_name_them(tmp_path, args, message):
    extra = ["--out", str(tmp_path / "o")] if args[0] == "build" else ["-o",
                                                                       str(tmp_path / "r.csv")]
    res = CliRunner().invoke(main, args + extra)
    assert res.exit_code == 2, (res.exit_code, res.output[-1500:])
    assert message in res.stderr and "internal error" not in res.stderr


def test_an_output_that_reads_an_input_is_a_static_relation():
    """A pump voltage read back (``y3 = u``) with a fault on it: the design tried a Kalman
    filter on that stateless output and stopped; now it is compared with the command."""
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.tune.model_update import fill_missing_thresholds

    model, _ = fill_missing_thresholds(load_model(DATA / "a4.toml"), 1.0)
    design = cached_design(model)
    (rel,) = [e for e in design.extra_residuals if e["check"] == "y3"]
    assert rel["realisation"] == "static relation" and rel["drivers"] == {}
    fault = next(f.name for f in design.model.faults if f.target == "y3")
    assert rel["residual"] in design.signature_table[fault]
