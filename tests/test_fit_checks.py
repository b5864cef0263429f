"""The output-error loop's checks of its own numbers (``fdigen.discover.fit_checks``): a
new user's heatsink got ``R_js = 0.5999 +- 0.48`` under a search bound of 0.6 written into
its model without a word, and two effects of identical BIC reported as one."""

from types import SimpleNamespace

import numpy as np

from fdigen.discover.fit_checks import at_bounds, output_error_ties, poorly_determined


def _fit(params, std):
    return SimpleNamespace(free=list(params), params=dict(params), std=dict(std))


def test_a_bound_inside_the_interval_decided_the_value():
    fit = _fit({"R_js": 0.5999, "h": 0.3, "k": 2.0}, {"R_js": 0.48, "h": 0.01, "k": None})
    bounds = {"R_js": (0.0, 0.6), "h": (0.0, 1.0), "k": (2.0, 10.0)}
    got = {(b["parameter"], b["side"]) for b in at_bounds(fit, bounds)}
    # R_js: 1e-4 from its upper bound, inside its +-0.48 (its lower bound, 0.5999 away,
    # is not); k exactly at its lower bound (no interval); h well inside
    assert got == {("R_js", "upper"), ("k", "lower")}
    tight = _fit({"R_js": 0.5999}, {"R_js": 1e-6})
    assert at_bounds(tight, bounds) == []        # 1e-4 away and known to 1e-6: the log's


def test_a_parameter_known_to_80_percent_is_reported():
    fit = _fit({"R_js": 0.6, "h": 0.3, "z": 0.0}, {"R_js": 0.48, "h": 0.01, "z": 1.0})
    got = poorly_determined(fit, ["R_js", "h", "z"])
    assert [p["parameter"] for p in got] == ["R_js"]
    assert np.isclose(got[0]["relative"], 0.8)


def test_candidates_within_two_of_the_chosen_bic_are_ties():
    chosen = [SimpleNamespace(name="external_load")]
    cands = [{"effect": "external_load", "round": 1, "delta_bic": -9878.8},
             {"effect": "coulomb_friction", "round": 1, "delta_bic": -9878.8},
             {"effect": "dead_band", "round": 1, "delta_bic": -9876.0},
             {"effect": "leak", "round": 2, "delta_bic": -9878.0}]
    got = output_error_ties(cands, chosen, 2.0)
    assert [t["other"] for t in got] == ["coulomb_friction"]
    assert got[0]["chosen"] == "external_load" and got[0]["round"] == 1
