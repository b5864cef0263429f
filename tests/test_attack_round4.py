"""Regressions of the fourth attack round (a reviewer from the outside, 2026-11-27):

* an HDF5 / MAT v7.3 log whose dataset is stored in another file (external storage, a
  virtual dataset, an external link) made fdigen read that file -- ``/dev/zero``, a
  secret, or a FIFO that hung it;
* a 98-character equation of nested sines kept ``inspect`` busy for minutes (the
  description's ``sympy.simplify``);
* a bound of 1e-50 and a threshold of 5e-324 became 0 in the float core (its ``_init``
  then accepted ``J = 0``);
* ``𝐊t`` and a full-width ``ｗ`` in an equation were read as ``Kt`` and ``w`` without a
  word;
* ``1_0`` in a log was read as 10, Arabic-Indic and full-width digits as numbers.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import sympy as sp

from fdigen.errors import LogError, ModelFileError
from fdigen.model.model_file import load_model


@pytest.fixture
def motor():
    return load_model("dc_motor")


def _h5_log(path, t, columns: dict, store):
    import h5py

    with h5py.File(path, "w") as f:
        f["t"] = t
        for name, values in columns.items():
            store(f, name, values)


@pytest.mark.parametrize("kind", ["external", "external_link", "soft_link"])
def test_an_hdf5_log_is_read_from_its_own_bytes_only(tmp_path, motor, kind):
    from fdigen.sim.log import read_log

    t = np.arange(200) * 1e-3
    secret = tmp_path / "secret.bin"
    np.arange(200, dtype="<f8").tofile(secret)
    other = tmp_path / "other.h5"
    import h5py

    with h5py.File(other, "w") as f:
        f["w"] = np.ones(200)

    def store(f, name, values):
        if name != "w":
            f[name] = values
        elif kind == "external":
            f.create_dataset("w", shape=(200,), dtype="<f8", external=[(str(secret), 0,
                                                                         200 * 8)])
        elif kind == "external_link":
            f["w"] = h5py.ExternalLink(str(other), "w")
        else:
            f["w_data"] = values
            f["w"] = h5py.SoftLink("/w_data")

    path = tmp_path / "log.h5"
    _h5_log(path, t, {"u": np.zeros(200), "w": np.zeros(200), "i": np.zeros(200)}, store)
    with pytest.raises(LogError, match="'w'.*(outside the log|link)"):
        read_log(path, motor)


def test_nested_functions_are_described_without_simplifying_them():
    from fdigen.design.describe import _simplified

    w = sp.Symbol("w", real=True)
    deep = w
    for _ in range(16):
        deep = sp.sin(deep)
    entry = sp.diff(deep, w)                 # what the description would simplify
    assert _simplified(entry) == str(entry)
    assert _simplified(sp.sin(w) ** 2 + sp.cos(w) ** 2) == "1"    # small ones still are


def test_values_below_a_c_float_are_refused_naming_the_field(motor):
    from fdigen.backends.c.emit import check_float_range

    J = next(q for q in motor.parameters if q.name == "J")
    tiny_bound = dataclasses.replace(motor, parameters=tuple(
        dataclasses.replace(q, bounds=(1e-50, 10.0)) if q is J else q
        for q in motor.parameters))
    with pytest.raises(ModelFileError, match=r"parameters\.J\.bounds.*below the range"):
        check_float_range(tiny_bound)
    thr = dataclasses.replace(motor, fdi={**motor.fdi, "thresholds": {
        **motor.fdi["thresholds"], "R1": 5e-324}})
    with pytest.raises(ModelFileError, match=r"fdi\.thresholds\.R1.*below the range"):
        check_float_range(thr)
    check_float_range(motor)                     # the shipped values pass


@pytest.mark.parametrize("text, shown", [("(𝐊t*i - b*w)/J", "'K'"),
                                         ("(Kt*i - b*ｗ)/J", "'w'")])
def test_look_alike_characters_in_an_equation_are_refused(text, shown):
    from fdigen.model.expression import parse_expression

    syms = {n: sp.Symbol(n, real=True) for n in ("Kt", "i", "b", "w", "J")}
    with pytest.raises(ModelFileError, match=f"non-ASCII character .*read as {shown}"):
        parse_expression(text, syms, source="m.toml", field="dynamics.w")


@pytest.mark.parametrize("field", ["1_0", "٠.5", "０.５"])
def test_log_values_are_plain_ascii_numbers(tmp_path, motor, field):
    from fdigen.sim.log import read_log

    rows = ["t,u,w,i"] + [f"{k * 1e-3:.3f},0,0,0" for k in range(20)]
    rows[5] = f"0.004,{field},0,0"
    path = tmp_path / "log.csv"
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    with pytest.raises(LogError, match=r"row 6, column 'u': not a number"):
        read_log(path, motor)


def test_a_removal_killed_halfway_is_finished_by_the_next_build(tmp_path):
    """The replaced folder loses its stamp first when deleted: killed then, it was no
    longer recognised and stayed for good. It is renamed to a name only that step gives
    before the removal starts."""
    from fdigen.files import folder_swap

    out = tmp_path / "out"
    (out / "dc_motor").mkdir(parents=True)
    (out / "dc_motor" / "new.c").write_text("new")
    half = out / ".dc_motor-deleting-0a1b2c3d"          # stamp already gone
    (half / "c").mkdir(parents=True)
    (half / "c" / "dc_motor_fdi.c").write_text("old")
    mine = out / ".dc_motor-deleting-notes"              # not a name fdigen gives
    mine.mkdir()
    done = folder_swap.recover_folder(out, "dc_motor", lambda p: False)
    assert done == ["removed .dc_motor-deleting-0a1b2c3d"]
    assert not half.exists() and mine.is_dir() and (out / "dc_motor" / "new.c").is_file()
    # and replace_folder leaves no old folder behind
    new = out / ".dc_motor-abcdefgh"
    new.mkdir()
    (new / "x.c").write_text("x")
    folder_swap.replace_folder(new, out / "dc_motor")
    assert sorted(p.name for p in out.iterdir()) == [".dc_motor-deleting-notes", "dc_motor"]
    assert (out / "dc_motor" / "x.c").is_file()


def test_the_ground_truth_names_the_log_it_belongs_to(tmp_path, monkeypatch):
    """simulate writes the log, then its truth: killed between the two, a new log sat
    beside the old truth with nothing to tell them apart."""
    import hashlib
    import json

    from click.testing import CliRunner

    from fdigen.cli import main

    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    log = tmp_path / "run.csv"
    res = CliRunner().invoke(main, ["simulate", "--model", "dc_motor", "-o", str(log),
                                    "--duration", "0.5"])
    assert res.exit_code == 0, res.output
    truth = json.loads(log.with_suffix(".json").read_text())
    assert truth["log_sha256"] == hashlib.sha256(log.read_bytes()).hexdigest()


def test_model_file_errors_are_one_line_and_give_the_real_reason():
    from fdigen.model.model_file import builtin_model_path, parse_model_text

    text = builtin_model_path("dc_motor").read_text()
    eq = next(line for line in text.splitlines() if line.startswith('w = "(Kt'))
    bad = text.replace(eq, eq[:-1] + '\\n+ 0"')
    with pytest.raises(ModelFileError) as err:
        parse_model_text(bad, "m.toml")
    assert "\n" not in str(err.value) and "\\n+ 0" in str(err.value)
    bad = text.replace("initial = { i = 0.0,", "initial = { i = nan,", 1)
    assert bad != text
    with pytest.raises(ModelFileError, match=r"simulation\.initial\.i.*finite number"):
        parse_model_text(bad, "m.toml")
