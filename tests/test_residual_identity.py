"""The model means what the user wrote (issue 20, part `ident`): stable identities of
derived residuals, inspect before tuning, isolability without the validity flags, each
residual's unit and noise level, and the small messages (default model, accommodate
without a voter, a commissioned file without effects)."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.design.cache import cached_design
from fdigen.design.config import ACCOMMODATE_WITHOUT_VOTER
from fdigen.design.fdi_design import fdi_design
from fdigen.design.observers import residual_noise_level
from fdigen.design.residual_identity import residual_key, residual_keys
from fdigen.design.residual_scale import residual_scales
from fdigen.errors import ModelFileError
from fdigen.model.model_file import load_model
from fdigen.pipeline import resolve_model_path, unkeyed_warning
from fdigen.tune.model_update import fill_missing_thresholds, updated_model_text

DATA = Path(__file__).parent / "data"
QUAD = DATA / "quadruple_tank.toml"
THREE = resolve_model_path("three_tank").read_text()
KEY4 = 'R4 = "Kalman filter: equations [h2] driven by [h1<-y1, h3<-y3], checked on y2"'
KEY5 = 'R5 = "Kalman filter: equations [h3] driven by [h2<-y2], checked on y3"'
KEY6 = ('R6 = "decoupled parallel model: equations [m_clog12] driven by [h1<-y1, h2<-y2, '
        'h3<-y3], checked on y1 + y2, blind to clog12"')


def _model(tmp_path, text, name="m.toml"):
    path = tmp_path / name
    path.write_text(text)
    return load_model(path)


def test_built_in_models_carry_the_keys_of_what_they_derive():
    for name in ("pneumatic_cylinder", "dc_motor", "three_tank", "heat_exchanger"):
        design = cached_design(load_model(name))
        assert design.extra_residuals, name
        assert design.unkeyed_thresholds == (), name
        assert design.config.residual_keys == residual_keys(design.extra_residuals)
    assert KEY4 in THREE and KEY5 in THREE


def test_key_is_what_the_residual_is_not_the_order_it_was_found_in():
    e = {"residual": "R4", "realisation": "Kalman filter", "equations": ["h3", "h2"],
         "drivers": {"h3": "y3", "h1": "y1"}, "check": "y2", "blind_to": None}
    again = dict(e, residual="R7", equations=["h2", "h3"], drivers={"h1": "y1", "h3": "y3"})
    assert residual_key(e) == residual_key(again)
    assert residual_key(e) != residual_key(dict(e, check="y1"))
    assert residual_key(e) != residual_key(dict(e, realisation="parallel model"))
    assert residual_key(dict(e, blind_to="valve")).endswith("blind to valve")


def test_threshold_written_for_another_residual_is_refused_naming_both(tmp_path):
    # an earlier numbering: R4 then meant today's R5; R5 a residual no longer derived
    stale = THREE.replace(KEY4 + "\n" + KEY5, "R4" + KEY5[2:] + "\nR5 = \"parallel model: "
                          "equations [h1] driven by [], checked on y1\"")
    assert stale != THREE
    path = tmp_path / "stale.toml"
    path.write_text(stale)
    # build, detect... refuse it (ModelFileError, exit 2); inspect shows the refusal, and
    # the table with stand-ins for the refused thresholds
    info = json.loads(_inspect("--model", str(path), "--json"))
    msg = info["thresholds_refused"]
    assert "field 'fdi.residual_keys', symbol 'R4'" in msg
    assert ("the threshold of R4 was written for 'Kalman filter: equations [h3] driven by "
            "[h2<-y2], checked on y3', but R4 is now 'Kalman filter: equations [h2] driven "
            "by [h1<-y1, h3<-y3], checked on y2'; this design derives that residual as R5"
            ) in msg
    assert ("the threshold of R5 was written for 'parallel model: equations [h1] driven by "
            "[], checked on y1', but R5 is now 'Kalman filter: equations [h3]") in msg
    assert "this design no longer derives that residual" in msg
    assert sorted(info["thresholds_missing"]) == ["R4", "R5"]
    assert info["unkeyed_thresholds"] == []
    assert info["signature_table"]["R4"]["clog12"] == 1


def test_unkeyed_derived_thresholds_load_with_a_warning(tmp_path):
    text = THREE.replace("[fdi.residual_keys]\n" + KEY4 + "\n" + KEY5 + "\n" + KEY6 + "\n",
                         "")
    assert "residual_keys" not in text
    design = fdi_design(_model(tmp_path, text))
    assert design.unkeyed_thresholds == ("R4", "R5", "R6")
    assert "R4, R5, R6 carry no residual key" in unkeyed_warning(design)[0]
    # the paper's residuals of the cylinder need none: their names are their identity
    assert cached_design(load_model()).unkeyed_thresholds == ()


@pytest.mark.parametrize("entry, match", [
    ('R1 = "x"', "for a derived residual"),
    ("R4 = 3", "a residual key is a text"),
    ('R9 = "x"', "a residual key without a threshold"),
])
def test_bad_residual_keys_are_refused(tmp_path, entry, match):
    text = THREE.replace(KEY5, KEY5 + "\n" + entry) if entry[:2] != "R4" else \
        THREE.replace(KEY4, entry)
    with pytest.raises(ModelFileError, match=match):
        load_model_and_config(tmp_path, text)


def load_model_and_config(tmp_path, text):
    from fdigen.design.config import read_fdi_config

    return read_fdi_config(_model(tmp_path, text))


def test_tune_write_text_records_the_keys_and_drops_thresholds_it_does_not_design(tmp_path):
    text = THREE.replace("[fdi.residual_keys]\n" + KEY4 + "\n" + KEY5 + "\n" + KEY6 + "\n",
                         "")
    text = text.replace("\nR5 = 1.05e-3", "\nR5 = 1.05e-3\nR7 = 1.0e-3")   # a stale one
    assert "R7 = 1.0e-3" in text
    design = cached_design(load_model("three_tank"))
    thresholds = {n: design.config.thresholds[n] for n in design.residual_names
                  if n in design.config.thresholds}
    keys = residual_keys(design.extra_residuals)
    new = updated_model_text(text, thresholds, keys=keys)
    assert "R7 =" not in new
    # placed after the table it belongs with, not before [fdi.actions]' closing comment
    assert new.index("[fdi.frozen_horizon]") < new.index("[fdi.residual_keys]") \
        < new.index("[fdi.actions]")
    assert load_model_and_config(tmp_path, new).residual_keys == keys
    assert updated_model_text(new, thresholds, keys=keys) == new


def _inspect(*args):
    res = CliRunner().invoke(main, ["inspect", *args])
    assert res.exit_code == 0, res.output
    return res.output


def test_inspect_before_tuning_shows_the_table_and_says_how_to_get_thresholds():
    model = load_model(QUAD)
    assert "thresholds" not in model.fdi
    info = json.loads(_inspect("--model", str(QUAD), "--json"))
    assert info["thresholds_missing"] == ["R1", "R2"]
    assert info["isolation"]["thresholds"]["R1"] is None
    assert info["signature_table"]["R2"]["pump1"] == 1
    text = _inspect("--model", str(QUAD))
    assert "Fault signature table" in text
    assert "no thresholds yet for R1, R2" in text and "fdigen tune --model FILE --write" in text


def test_achieved_isolability_leaves_out_the_validity_flags():
    info = json.loads(_inspect("--model", str(QUAD), "--json"))
    iso = info["isolability"]
    faults = iso["faults"]
    s1, leak1 = faults.index("s1"), faults.index("leak1")
    # structure: a level-1 sensor offset cannot be told from a leak of tank 1
    assert iso["achievable"][s1][leak1] == 0
    assert iso["achieved"][s1][leak1] == 0          # was 1, through nf_y1 alone
    assert ["s1", "leak1"] in iso["isolable_only_when_the_sensor_dies"]
    assert iso["achieved_not_achievable"] == []
    # the two counts compare the same kind of pairs, and the difference is listed
    achieved = {tuple(p) for p in iso["achieved_non_isolable"]}
    achievable = {tuple(p) for p in iso["achievable_non_isolable"]}
    assert {tuple(p) for p in iso["achievable_not_achieved"]} == achieved - achievable
    text = _inspect("--model", str(QUAD))
    assert "(different pairs: below)" in text
    assert "isolable only when the sensor dies" in text


def test_no_built_in_model_claims_more_than_its_structure():
    from fdigen.design.describe import validity_flags
    from fdigen.design.structure import isolability_report

    for name in ("pneumatic_cylinder", "dc_motor", "three_tank", "heat_exchanger"):
        design = cached_design(load_model(name))
        rep = isolability_report(design.model, design.signature_table, validity_flags(design))
        assert rep["achieved_not_achievable"] == [], name


def test_each_residual_has_its_unit_and_noise_level():
    design = cached_design(load_model())
    sc = residual_scales(design)
    model = design.model
    assert sc["R1"]["unit"] == model.output("x3").unit == "m"
    assert sc["R1"]["noise_level"] == model.output("x3").noise_std
    assert sc["R2"]["unit"] == "Pa"
    kal = {k.residual: k for k in design.kalman}
    for name in ("R4", "R5", "R6"):
        assert sc[name]["noise_level"] == residual_noise_level(kal[name])
    assert sc["R5"]["unit"] == "Pa"                      # pp - pn
    # a pressure times a volume (design/unit_algebra.py; it read "that of the expression
    # (pn: Pa, V0: m^3, ...)")
    assert sc["R7"]["unit"] == "Pa*m^3"
    # R7 = pn*(A*L - A*x3 + V0) + pp*(A*x3 + V0): sensor noise carried through
    p = {q.name: q.value for q in model.parameters}
    op = model.operating_point
    x3 = float(op["x"]) if not isinstance(op["x"], str) else p["L"] / 2
    grads = {"pn": p["A"] * p["L"] - p["A"] * x3 + p["V0"], "pp": p["A"] * x3 + p["V0"]}
    lower = np.hypot(grads["pn"] * model.output("pn").noise_std,
                     grads["pp"] * model.output("pp").noise_std)
    assert sc["R7"]["noise_level"] >= lower * (1 - 1e-9)
    assert sc["w1"]["noise_level"] is None and sc["nf_x3"]["unit"] == "1"
    quad = residual_scales(cached_design(fill_missing_thresholds(load_model(QUAD), 1e30)[0]))
    assert quad["R1"]["unit"] == "V"
    text = _inspect()
    assert "threshold / noise" in text


def test_detect_without_model_names_the_default(tmp_path):
    log = tmp_path / "three_tank.csv"
    log.write_text("t,q1,q2,h1,h2,h3\n0,3e-5,3e-5,0.4,0.3,0.2\n0.1,3e-5,3e-5,0.4,0.3,0.2\n")
    res = CliRunner().invoke(main, ["detect", str(log)])
    assert res.exit_code == 2
    assert "the default model is pneumatic_cylinder: pass --model" in res.output
    res = CliRunner().invoke(main, ["detect", str(log), "--model", "pneumatic_cylinder"])
    assert res.exit_code == 2 and "default model" not in res.output
    res = CliRunner().invoke(main, ["report", str(log), "-o", str(tmp_path / "r.html")])
    assert res.exit_code == 2
    assert "the default model is pneumatic_cylinder: pass --model" in res.output


def test_accommodate_without_a_voter_says_what_it_does():
    assert load_model("dc_motor").fdi["actions"]["tachometer"] == "accommodate"
    assert ACCOMMODATE_WITHOUT_VOTER in _inspect("--model", "dc_motor").replace("\n", " ")
    assert "no [fdi.voter]" not in _inspect()           # the cylinder has a voter


def test_augmented_header_without_an_effect_says_none_was_found():
    from fdigen.discover.augment import augmented_text

    text = resolve_model_path("three_tank").read_text()
    head = augmented_text(text, load_model("three_tank"), [], {},
                          calibrated={"az12": 0.5}, origin="healthy.csv").split("\n", 1)[0]
    assert "no effect found, none added" in head and ": added" not in head


def _stated_default(text, key):
    import re

    found = re.search(rf"`{key}` \((?:boolean|integer), default `([a-z0-9]+)`\)", text)
    assert found, f"README does not state the default of {key}"
    return {"true": True, "false": False}.get(found.group(1), found.group(1))


def test_readme_explains_the_residual_keys_with_the_defaults_the_code_uses(tmp_path,
                                                                           cylinder_design):
    import dataclasses

    from fdigen.design.config import read_fdi_config

    readme = (Path(__file__).parents[1] / "README.md").read_text()
    iso = (Path(__file__).parents[1] / "docs" / "isolation.md").read_text()
    fdi = {k: v for k, v in load_model("three_tank").fdi.items()
           if k not in ("extra_residuals", "isolate_within_classes", "isolate_structurally")}
    cfg = read_fdi_config(dataclasses.replace(load_model("three_tank"), fdi=fdi))
    assert cfg.extra_residuals is _stated_default(readme, "extra_residuals")
    assert cfg.isolate_structurally is _stated_default(readme, "isolate_structurally")
    assert cfg.isolate_within_classes == int(_stated_default(readme, "isolate_within_classes"))
    for key in ("extra_residuals", "isolate_within_classes", "isolate_structurally"):
        assert f"| `{key}` |" in iso
    # the cylinder's examples: R6 for the classes, R7 decoupled within a class, R8/R9 cover
    kinds = {e["residual"]: (e["realisation"], e["purpose"])
             for e in cylinder_design.extra_residuals}
    assert kinds["R6"] == ("Kalman filter", "isolate classes")
    assert kinds["R7"] == ("decoupled parallel model", "isolate faults")
    assert kinds["R8"][1] == kinds["R9"][1] == "isolate faults to the structural isolability"
    # extra_residuals = false: nothing derived, whatever the two other keys say
    fdi = dict(load_model("three_tank").fdi, extra_residuals=False, isolate_structurally=True,
               isolate_within_classes=2)
    fdi["thresholds"] = {k: v for k, v in fdi["thresholds"].items()
                         if k not in ("R4", "R5", "R6")}
    fdi.pop("residual_keys")
    fdi["frozen_horizon"] = {k: v for k, v in fdi["frozen_horizon"].items() if k != "R6"}
    design = fdi_design(dataclasses.replace(load_model("three_tank"), fdi=fdi))
    assert design.extra_residuals == ()

