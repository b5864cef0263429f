"""The innovation low-pass of derived Kalman residuals (fdigen.design.innovation_filter)
and tune's search for it (fdigen.tune.filter_search)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from fdigen.backends.reference import ReferenceFdi
from fdigen.design.fdi_design import fdi_design
from fdigen.design.innovation_filter import innovation_alpha, noise_factor
from fdigen.design.residual_scale import residual_scales
from fdigen.errors import ModelFileError
from fdigen.model.model_file import parse_model_text
from fdigen.pipeline import resolve_model_path as builtin_model_path
from fdigen.sim.plant import FaultEvent, simulate
from fdigen.tune.filter_search import filter_to_try, isolates_more

TAU = 5.0


def _text(tau: float | None) -> str:
    text = builtin_model_path("three_tank").read_text(encoding="utf-8")
    if tau is None:
        return text
    # the shipped keys name the unfiltered residuals: drop them (thresholds then unkeyed)
    text = re.sub(r'^R[45] = "Kalman filter:[^\n]*\n', "", text, flags=re.M)
    return text.replace("extra_residuals = true",
                        f"extra_residuals = true\ninnovation_filter = {tau}")


@pytest.fixture(scope="module")
def designs():
    return (fdi_design(parse_model_text(_text(None), "three_tank.toml")),
            fdi_design(parse_model_text(_text(TAU), "three_tank_lp.toml")))


def test_filtered_residuals_and_keys(designs):
    raw, lp = designs
    derived_kalman = [k.residual for k in lp.kalman]
    assert derived_kalman == ["R4", "R5"]
    for name in derived_kalman:
        assert f"{name}_lp" in lp.state_names and f"{name}_lp" not in raw.state_names
    keys = {e["residual"]: e["realisation"] for e in lp.extra_residuals}
    assert keys["R4"] == f"Kalman filter, innovation low-passed over {TAU:g} s"
    # the key changed: the shipped model's keyed thresholds are refused for the filtered
    text = builtin_model_path("three_tank").read_text(encoding="utf-8").replace(
        "extra_residuals = true", "extra_residuals = true\ninnovation_filter = 5.0")
    with pytest.raises(ModelFileError, match="innovation low-passed over 5 s"):
        fdi_design(parse_model_text(text, "stale.toml"))


def test_noise_level_scaled(designs):
    raw, lp = designs
    s0, s1 = residual_scales(raw), residual_scales(lp)
    alpha = innovation_alpha(TAU, raw.config.sample_time)
    assert alpha == pytest.approx(math.exp(-0.1 / 5.0))
    for name in ("R4", "R5"):
        assert s1[name]["noise_level"] == pytest.approx(
            s0[name]["noise_level"] * math.sqrt((1 - alpha) / (1 + alpha)), rel=1e-12)
    for name in ("R1", "R2", "R3"):
        assert s1[name]["noise_level"] == s0[name]["noise_level"]


@pytest.fixture(scope="module")
def offset_log(designs):
    raw, _ = designs
    return simulate(raw.model, 300.0, faults=(FaultEvent("s2", 100.0, 0.02),), seed=3)


def test_filtered_residual_is_the_low_pass_of_the_innovation(designs, offset_log):
    """The Kalman update reads the raw innovation, so the unfiltered design's residual
    is the filtered design's innovation, sample for sample: the filtered residual must be
    its first-order low-pass from 0."""
    raw, lp = designs
    a = ReferenceFdi(raw).run(offset_log.u, offset_log.y)
    b = ReferenceFdi(lp).run(offset_log.u, offset_log.y)
    alpha = innovation_alpha(TAU, raw.config.sample_time)
    for name in ("R4", "R5"):
        i = raw.residual_names.index(name)
        e, w = a["r"][:, i], b["r"][:, i]
        expect = np.empty_like(e)
        prev = 0.0
        for k, ek in enumerate(e):
            prev = alpha * prev + (1 - alpha) * ek
            expect[k] = prev
        scale = np.max(np.abs(e))
        assert np.max(np.abs(w - expect)) <= 1e-12 * scale
    # the other residuals are untouched until a flag freezes the parallel models (the
    # flags differ: R4, R5 are not the same residuals)
    first = min(int(np.argmax(o["flags"] != 0)) for o in (a, b))
    assert first > 500
    for name in ("R1", "R2", "R3"):
        i = raw.residual_names.index(name)
        assert np.array_equal(a["r"][:first + 1, i], b["r"][:first + 1, i])


def test_bias_stands_out_of_the_filtered_noise(designs, offset_log):
    """A 2 cm offset on level sensor 2 (a driving sensor of R5, nominal parameters):
    the raw innovation's RMS barely leaves its noise level, the filtered one's rises well
    above its own."""
    raw, lp = designs
    k0 = int(150.0 / raw.config.sample_time)          # a window after the onset
    ratios = []
    for design in (raw, lp):
        out = ReferenceFdi(design).run(offset_log.u, offset_log.y)
        i = design.residual_names.index("R5")
        level = residual_scales(design)["R5"]["noise_level"]
        ratios.append(float(np.median(out["rms"][k0:, i])) / level)
    assert ratios[0] < 1.3
    assert ratios[1] > 2.5 * ratios[0]


def test_config_refuses_negative_time_constant():
    text = _text(None).replace("extra_residuals = true",
                               "extra_residuals = true\ninnovation_filter = -1.0")
    with pytest.raises(ModelFileError, match="innovation_filter"):
        fdi_design(parse_model_text(text, "neg.toml"))


def _report(isolated_runs=0, keys=None, poorly=None):
    return {"residual_keys": keys or {}, "poorly_isolated": poorly or {},
            "isolated_runs": isolated_runs}


def test_filter_search_trigger(designs):
    raw, lp = designs
    kal_keys = {"R4": "Kalman filter: equations [h2] driven by [h1<-y1, h3<-y3], checked on y2"}
    assert filter_to_try(_report(keys=kal_keys, poorly={"s2": 0.0}), raw.model) == \
        pytest.approx(0.5 * 100 * 0.1)
    assert filter_to_try(_report(keys=kal_keys), raw.model) is None        # all isolated
    assert filter_to_try(_report(keys={"R4": "parallel model: ..."}, poorly={"s2": 0.0}),
                         raw.model) is None                                 # no Kalman
    assert filter_to_try(_report(keys=kal_keys, poorly={"s2": 0.0}), lp.model) is None


def test_filter_taken_only_when_better_on_every_count():
    base = {"detected": [("s2", "step"), ("s3", "step")], "isolated_runs": 7,
            "wrong_isolations": 0, "validation_false_alarms": 0}
    assert isolates_more(base, {**base, "isolated_runs": 10})
    assert not isolates_more(base, {**base, "isolated_runs": 7})
    assert not isolates_more(base, {**base, "isolated_runs": 10,
                                    "detected": [("s2", "step")]})
    assert not isolates_more(base, {**base, "isolated_runs": 10, "wrong_isolations": 1})
    assert not isolates_more(base, {**base, "isolated_runs": 10,
                                    "validation_false_alarms": 1})
