"""``[fdi] startup``: the core raises no flag during its first seconds, in every backend.

A battery's hidden state of charge starts wherever the last drive left it (round 52): the
core starts it at ``[operating_point]``, and its residuals stay high until the observers
and parallel models have followed. ``tests/data/startup/two_rooms_startup.toml`` has a
threshold far below the noise, so without the start-up its flag rises on the first
samples.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main

MODEL = Path(__file__).parent / "data" / "startup" / "two_rooms_startup.toml"
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]


@pytest.fixture(scope="module")
def design():
    from fdigen.design.fdi_design import fdi_design
    from fdigen.model.model_file import load_model

    return fdi_design(load_model(MODEL))


@pytest.fixture(scope="module")
def log(design):
    from fdigen.sim.plant import simulate

    sim = simulate(design.model, 10.0, seed=3)
    return sim.u, sim.y


def _backends(design, tmp):
    from fdigen.backends.c import CFdi
    from fdigen.backends.casadi_backend import CasadiFdi
    from fdigen.backends.reference import ReferenceFdi

    return {"reference": ReferenceFdi(design), "casadi_sx": CasadiFdi(design),
            "casadi_compiled": CasadiFdi(design, compiled=True, cache_dir=tmp / "casadi"),
            "c": CFdi(design, cache_dir=tmp / "c"),
            "c_float": CFdi(design, float_type="float", cache_dir=tmp / "cf")}


def test_no_flag_rises_before_the_start_up_ends_in_any_backend(design, log, tmp_path):
    S = design.evaluation.startup
    assert S == 150                                  # 3 s at 0.02 s
    runs = {name: fdi.run(*log) for name, fdi in _backends(design, tmp_path).items()}
    ref = runs.pop("reference")
    flags = np.asarray(ref["flags"])
    assert not flags[:S].any() and flags[S] != 0     # the first sample allowed raises it
    for name, out in runs.items():
        assert np.array_equal(np.asarray(out["flags"]), flags), name
        assert np.array_equal(np.asarray(out["fault_class"]), np.asarray(ref["fault_class"])), name
    # without the start-up the same core flags on its first samples
    from dataclasses import replace

    from fdigen.backends.reference import ReferenceFdi

    plain = ReferenceFdi(replace(design, evaluation=replace(design.evaluation, startup=0)))
    out = plain.run(*log)
    first = int(np.argmax(np.asarray(out["flags"]) != 0))
    assert np.asarray(out["flags"])[first] != 0 and first < 10
    # the residuals and their RMS run from the first sample: equal up to that first flag
    # (a flag freezes the parallel models' realignment)
    np.testing.assert_array_equal(np.asarray(out["rms"])[:first + 1],
                                  np.asarray(ref["rms"])[:first + 1])


def test_reset_starts_the_start_up_again(design, log):
    from fdigen.backends.reference import ReferenceFdi

    fdi = ReferenceFdi(design)
    u, y = log
    for k in range(200):
        fdi.step(u[k], y[k])
    assert fdi.state.flags
    fdi.reset()
    assert all(fdi.step(u[k], y[k])["flags"] == 0 for k in range(150))


def test_a_corrupted_start_up_count_raises_the_flags_at_once(design, log, tmp_path):
    """A count outside ``[0, S]`` is a corrupted state: its residuals read an infinite
    RMS and flag at once, whatever the count says of the start-up."""
    u, y = log
    fdi = _backends(design, tmp_path)
    for name in ("reference", "c"):
        core = fdi[name]
        core.step(u[0], y[0])
        core.state.elapsed = -1000
        out = core.step(u[1], y[1])
        assert out["flags"] != 0, name
        assert np.all(np.isinf(np.asarray(out["rms"]))), name


@pytest.mark.parametrize("float_type,extra", [("double", []), ("float", ["-Wconversion"])])
def test_the_start_up_compiles_strictly(design, tmp_path, float_type, extra):
    from fdigen.backends.c.emit import render_c_sources
    from fdigen.model.model_file import model_hash

    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed")
    files = render_c_sources(design, float_type=float_type, model_source=MODEL.name,
                             model_hash=model_hash(design.model))
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    c = f"{design.name}_fdi.c"
    assert "elapsed" in files[c]
    proc = subprocess.run(["gcc", *STRICT, *extra, "-O2", "-c", c, "main.c"], cwd=tmp_path,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("value,problem", [("-1.0", "must be 0 or more seconds"),
                                           ('"3 s"', "number"),
                                           ("1e11", "at most 2^31 - 1 samples")])
def test_a_bad_start_up_is_refused(tmp_path, value, problem):
    bad = tmp_path / "bad.toml"
    bad.write_text(MODEL.read_text().replace("startup = 3.0", f"startup = {value}"))
    res = CliRunner().invoke(main, ["inspect", "--model", str(bad)])
    assert res.exit_code == 2, res.output
    assert "startup" in res.output and problem in res.output, res.output


SLAB = Path(__file__).parent / "data" / "startup" / "hidden_slab.toml"


def test_tune_measures_the_start_up_of_a_hidden_state_that_starts_anywhere(tmp_path):
    """A room's slab (hidden) starts anywhere in 10-30 degC (``[simulation.initial] Ts =
    [10.0, 30.0]``, one draw per run): the air residual's healthy maximum comes at the
    start, about 4 x its maximum over the last third. Tune measures the start-up after
    which every healthy run has come down, fits the thresholds after it, checks them with
    it, and writes it."""
    import tomllib

    model = tmp_path / "hidden_slab.toml"
    model.write_text(SLAB.read_text())
    report = tmp_path / "tune.json"
    res = CliRunner().invoke(main, [
        "tune", "--model", str(model), "--runs", "4", "--validation-runs", "2",
        "--fault-sizes", "1", "--fault-starts", "1", "--scheduler", "synchronous",
        "--no-realign-search", "--no-filter-search", "--no-class-search",
        "--no-hold-search", "--report", str(report), "--write"])
    assert res.exit_code in (0, 1), res.output
    import json

    rep = json.loads(report.read_text())
    su = rep["startup"]
    assert su and su["residuals"] == ["Ra"]
    assert 0 < max(su["settled"].values()) <= su["seconds"] <= 40000.0 / 3 + 1e-6
    assert "Ra" not in rep["false_alarm"]["early_peaks"]
    assert rep["false_alarm"]["validation_false_alarms"] == 0
    fdi = tomllib.loads(model.read_text())["fdi"]
    assert fdi["startup"] == su["seconds"]
    # the threshold clears the healthy runs after the start-up, not their start
    runs = rep["runs"]["healthy"]
    start_max = max(max(r["suffix_max"]["max"][0][0] for r in runs), 0.0)
    assert fdi["thresholds"]["Ra"] < start_max
    # every run the campaign simulated started its slab somewhere else
    from fdigen.model.model_file import load_model
    from fdigen.sim.plant import simulate

    m = load_model(model)
    starts = {round(float(simulate(m, 100.0, seed=s).x[0, 1]), 6) for s in range(4)}
    assert len(starts) == 4 and all(10.0 <= v <= 30.0 for v in starts)
