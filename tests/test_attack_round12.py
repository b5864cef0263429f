"""Attack round 12: the nonlinear prediction of driven filters, the conditional spreads,
the output-error loop's figure (tests/data/attack12)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

DATA = Path(__file__).parent / "data" / "attack12"


def test_a_drivers_glitch_under_a_sqrt_does_not_kill_the_filter(tmp_path):
    """Two tanks, ``sqrt(h1 - h2)`` unguarded: three samples of h1 = 0.03 (finite, inside
    the limits, below h2) made the driven filter R2's prediction NaN, and R2 stayed NaN
    for the remaining 299 samples, said nowhere. The prediction outside the equations'
    domain now holds the updated estimate, and the filter recovers."""
    from fdigen.design.cache import cached_design
    from fdigen.detect import run_log
    from fdigen.model.model_file import load_model

    design = cached_design(load_model(DATA / "tt_sqrt.toml"))
    assert any(k.schedule == "nonlinear" for k in design.kalman)
    for backend in ("c", "reference", "casadi"):
        summary, out, _ = run_log(design, DATA / "glitch.csv", backend)
        r = np.asarray(out["r"])
        assert np.all(np.isfinite(r)), backend
        assert np.all(np.isfinite(np.asarray(out["rms"])[-1])), backend


def test_a_diverging_free_run_is_drawn(tmp_path):
    from fdigen.discover.report import plot_free_run

    model = SimpleNamespace(outputs=[SimpleNamespace(name="y", unit="m")])
    t = np.linspace(0, 100, 1001)
    y = np.sin(t)[:, None]
    with np.errstate(all="ignore"):
        run = (np.cos(3 * t) * 1.01 ** np.arange(1001.0) * 1e304)[:, None]
    path = plot_free_run(tmp_path / "f.png", model, t, y, run, y, title="t")
    assert path.stat().st_size > 0


def test_a_parameter_the_log_does_not_move_has_no_interval():
    """A zero column of the Jacobian: the pseudo-inverse gave it 0, a parameter known
    exactly, spread by the floor alone and listed as "the log: +-0 %"."""
    from fdigen.commission.spread import conditional_or_marginal, floor_bound
    from fdigen.discover.sensitivity import conditional_deviations, standard_deviations

    rng = np.random.default_rng(0)
    J = np.c_[rng.standard_normal(50), np.zeros(50), rng.standard_normal(50)]
    fit = SimpleNamespace(J=J, free=["p", "z", "q"], n=50, sse=50.0,
                          params={"p": 1.0, "z": 2.0, "q": 3.0})
    marginal = standard_deviations(fit, np.array([1.0]))
    alone = conditional_deviations(fit, np.array([1.0]))
    assert marginal["z"] == alone["z"] == float("inf")
    picked = conditional_or_marginal(marginal, alone)
    assert picked["z"] == float("inf")
    assert "z" not in floor_bound(fit.params, picked, 3.0, 0.05)["names"]
    assert "d" not in floor_bound({"d": 1.0}, {"d": 0.0}, 3.0, 0.05)["names"]
