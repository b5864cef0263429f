"""A model whose thresholds are not designed yet is derived in rounds (``inspect`` and
``tune`` fill missing thresholds and derive again): the refusal of a derivation that
lacks only thresholds is cached, the observable reductions are reused within a process,
and a symbolic step that runs out of its budget prints one clean note.

The first-time user's electro-hydraulic servo took 6 min 52 s to inspect, and 3 min 46 s
again with the same cache: the derivation refused for missing derived thresholds was
never cached, and each of the two derivations per run repeated a 60 s symbolic attempt.
"""

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fdigen.model.model_file import load_model

DATA = Path(__file__).parent / "data" / "newuser"


def test_a_refusal_for_missing_thresholds_is_cached(tmp_path, monkeypatch):
    from fdigen.design import fdi_design as derivation
    from fdigen.design.cache import cached_design, design_path
    from fdigen.errors import FdigenError

    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path))
    model = load_model(str(DATA / "twotank_cm.toml"))      # no [fdi.thresholds] at all
    with pytest.raises(FdigenError) as first:
        cached_design(model)
    assert first.value.missing_thresholds == ("R1", "R2")
    assert design_path(model).with_suffix(".refused").is_file()

    def must_not_derive(model):
        raise AssertionError("derived again")

    monkeypatch.setattr(derivation, "fdi_design", must_not_derive)
    with pytest.raises(FdigenError) as again:
        cached_design(model)
    assert again.value.missing_thresholds == ("R1", "R2")
    assert str(again.value) == str(first.value)

    # the same file in another folder: the cached refusal names that folder's copy (a
    # user's discover into outB was told of outA's file)
    other = tmp_path / "outB"
    other.mkdir()
    copy = other / "twotank_cm.toml"
    copy.write_bytes((DATA / "twotank_cm.toml").read_bytes())
    with pytest.raises(FdigenError) as moved:
        cached_design(load_model(str(copy)))
    assert str(copy) in str(moved.value)
    assert str(DATA / "twotank_cm.toml") not in str(moved.value)
    assert moved.value.missing_thresholds == ("R1", "R2")


def test_observable_reductions_are_reused_across_thresholds(monkeypatch, cylinder):
    from fdigen.derive.observability import observable_reduction
    from fdigen.errors import FdigenNote

    servo = load_model(str(DATA / "dc_servo_50ms.toml"))
    red = observable_reduction(servo, ("enc",))
    other = dataclasses.replace(servo, fdi={**servo.fdi, "thresholds": {"P1": 1.0, "K1": 2.0}})
    assert observable_reduction(other, ("enc",)) is red          # thresholds: same physics
    assert red.rank == 3 and red.numeric_fallback == ""
    heavier = dataclasses.replace(servo, parameters=tuple(
        dataclasses.replace(q, value=2 * q.value) if q.name == "J" else q
        for q in servo.parameters))
    assert observable_reduction(heavier, ("enc",)) is not red    # other physics: derived
    monkeypatch.setenv("FDIGEN_SYMBOLIC_BUDGET", "1e-6")          # another budget: derived
    with pytest.warns(FdigenNote, match="exceeded its budget"):
        fallback = observable_reduction(cylinder, ("x3",))
    assert fallback.numeric_fallback
    with pytest.warns(FdigenNote, match="exceeded its budget"):    # reused: noted again
        assert observable_reduction(cylinder, ("x3",)) is fallback


def test_fdigen_notes_are_one_clean_line_and_library_warnings_go_to_the_log(tmp_path):
    code = ("import warnings\n"
            "from fdigen.errors import FdigenNote\n"
            "from fdigen.library_log import route_library_output\n"
            "route_library_output()\n"
            "for _ in range(2):\n"
            "    warnings.warn('m.toml: the symbolic step fell back', FdigenNote)\n"
            "warnings.warn('a library detail', RuntimeWarning)\n")
    env = {**os.environ, "FDIGEN_CACHE": str(tmp_path)}
    env.pop("FDIGEN_DEBUG", None)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stderr.splitlines() == ["fdigen: note: m.toml: the symbolic step fell back"]
    log = (tmp_path / "fdigen.log").read_text()
    assert "a library detail" in log and "fell back" not in log


def test_a_design_differing_only_in_its_evaluation_is_set_equal_to_its_derivation():
    """tune and commission derive the same model with other threshold values, horizons
    or class decision (7 derivations in one `commission` of the cylinder). Such a model's
    design is set from the one this process derived (design/retarget.py): it must be the
    design a derivation gives -- same configuration, same evaluation, same C bytes."""
    from fdigen.backends.c.emit import render_c_sources
    from fdigen.design import fdi_design as derivation
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import model_hash
    from fdigen.tune.model_update import design_with_thresholds, model_with_thresholds

    def c_files(d):
        return render_c_sources(d, float_type="double", model_source="m.toml",
                                model_hash=model_hash(d.model))

    def same(quick, derived):
        assert quick.model == derived.model
        assert repr(quick.config) == repr(derived.config)
        for field in dataclasses.fields(derived.evaluation):
            a, b = (getattr(d.evaluation, field.name) for d in (quick, derived))
            assert repr(a) == repr(b), field.name
        assert c_files(quick) == c_files(derived)

    model = load_model("three_tank")
    base = cached_design(model)
    new = {n: 1.37 * v for n, v in model.fdi["thresholds"].items()}
    calls = []
    real = derivation.fdi_design
    try:
        derivation.fdi_design = lambda m: calls.append(m) or real(m)
        quick = design_with_thresholds(model, new)
        other = dataclasses.replace(model, fdi={
            **model.fdi, "structural_classes": not model.fdi.get("structural_classes"),
            "frozen_horizon": {k: 2.5 * v for k, v in model.fdi["frozen_horizon"].items()}})
        quick2 = cached_design(other)
    finally:
        derivation.fdi_design = real
    same(quick, real(model_with_thresholds(model, new)))
    same(quick2, real(other))
    assert calls == []          # neither was derived
    rms = [i for i, n in enumerate(base.evaluation.residuals) if not n.startswith("nf_")]
    assert not (quick.evaluation.thresholds[rms] == base.evaluation.thresholds[rms]).any()
    assert quick2.evaluation.class_flags != base.evaluation.class_flags
    assert quick2.evaluation.horizons != base.evaluation.horizons


def test_a_cached_design_names_the_file_read_now(tmp_path, monkeypatch):
    """The cache key leaves the model file's folder out, so a checkout elsewhere (CI's
    copy of the tree, a user's second project folder) is served the design stored from
    the first: the design it returns must name the file read now, as a derivation of it
    would (CI found ``/work/ci/...`` in a design of ``/check/work/main/...``)."""
    import shutil

    from fdigen.design import fdi_design as derivation
    from fdigen.design.cache import _SIBLINGS, cached_design, design_path

    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    shipped = Path(load_model("three_tank").source)
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        shutil.copy(shipped, tmp_path / folder / shipped.name)
    first = load_model(str(tmp_path / "a" / shipped.name))
    cached_design(first)
    assert design_path(first).is_file()
    _SIBLINGS.clear()

    def must_not_derive(model):
        raise AssertionError("derived again")

    monkeypatch.setattr(derivation, "fdi_design", must_not_derive)
    second = load_model(str(tmp_path / "b" / shipped.name))
    served = cached_design(second)
    assert str(served.model.source) == str(tmp_path / "b" / shipped.name)
    assert served.model == second
