"""Attack round 8: numbers a double cannot hold, kinks at the operating point, and logs
whose few bytes expand into gigabytes.

Each case was an internal error (exit 3), a core that read NaN on a healthy log while
`build` and `verify` said OK, or gigabytes of memory for a file of kilobytes.
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main
from fdigen.errors import LogError, ModelFileError
from fdigen.model.model_file import parse_model_text
from fdigen.pipeline import resolve_model_path

MOTOR = resolve_model_path("dc_motor").read_text()
HUGE = "1" + "0" * 400


@pytest.mark.parametrize("old,new,field", [
    ('Ra = { value = 1.2,', f'Ra = {{ value = {HUGE},', "parameters.Ra.value"),
    ("bounds = [0.01, 13.9]", f"bounds = [0.01, {HUGE}]", "parameters.Ra.bounds"),
    ('w = { unit = "rad/s", description = "shaft speed", range = [-300.0, 300.0] }',
     f'w = {{ unit = "rad/s", description = "shaft speed", range = [-300.0, {HUGE}] }}',
     "states.w.range"),
    ('V = "Vnom"', f"V = {HUGE}", "operating_point.V"),
    ("realign_noise_scale = 0.05", f"realign_noise_scale = {HUGE}",
     "fdi.realign_noise_scale"),
    ("Rw = 1.46", f"Rw = {HUGE}", "fdi.thresholds.Rw"),
])
def test_integers_beyond_a_double_are_refused_naming_the_field(old, new, field):
    """tomllib reads them as Python ints; `math.isfinite` raised OverflowError."""
    assert old in MOTOR
    text = MOTOR.replace(old, new, 1)
    from fdigen.design.config import read_fdi_config

    with pytest.raises(ModelFileError, match="magnitude beyond") as err:
        read_fdi_config(parse_model_text(text, source="m.toml"))     # [fdi]: read there
    # (an [fdi] number may be as large as a double: a threshold of 1e300 never flags)
    assert field in str(err.value)


def test_an_integer_tomllib_cannot_read_is_invalid_toml():
    text = MOTOR.replace('Ra = { value = 1.2,', 'Ra = { value = 1' + "0" * 5000 + ',', 1)
    with pytest.raises(ModelFileError, match="invalid TOML: a number"):
        parse_model_text(text, source="m.toml")


def test_a_mistyped_threshold_names_the_residual_not_its_value():
    from fdigen.design.config import read_fdi_config

    text = MOTOR.replace("Rw = 1.46", "Rw = true", 1)
    with pytest.raises(ModelFileError, match="expected a number, got bool") as err:
        read_fdi_config(parse_model_text(text, source="m.toml"))
    assert "symbol 'Rw'" in str(err.value)


@pytest.mark.parametrize("term", ["asin(V/Vnom)", "acos(V/Vnom)"])
def test_a_derivative_that_is_not_real_at_the_operating_point_is_a_usage_error(term,
                                                                             tmp_path):
    """asin'(x) at x = 1 is infinite (sympy: complex): 'Cannot convert complex to float'."""
    model = tmp_path / "m.toml"
    model.write_text(MOTOR.replace('w = "(Kt*i - b*w)/J"',
                                   f'w = "(Kt*i - b*w)/J - 1e-3*{term}/J"', 1))
    res = CliRunner().invoke(main, ["inspect", "--model", str(model)])
    assert res.exit_code == 2, res.output[-2000:]
    assert "not real at" in res.output and "V = 12" in res.output


def test_a_kink_at_the_operating_point_derives_no_combination_that_switches(tmp_path):
    """max(V - Vnom, 0) at V = Vnom: a decoupled combination weighted by
    Heaviside(V - Vnom) was derived, then its initial state read the input V."""
    model = tmp_path / "m.toml"
    model.write_text(MOTOR.replace('w = "(Kt*i - b*w)/J"',
                                   'w = "(Kt*i - b*w)/J - 1e-3*max(V - Vnom, 0)/J"', 1))
    res = CliRunner().invoke(main, ["inspect", "--model", str(model)])
    assert res.exit_code == 0, res.output[-2000:]
    assert "Heaviside" not in res.output


def test_terms_beyond_a_double_or_a_float_at_the_operating_point_are_refused(tmp_path):
    """`1e-300*cosh(700*Ra) - 1e-300*sinh(700*Ra)` is finite, but inf - inf in every
    backend: the core read NaN on a healthy log and `verify` said OK. A float-only
    overflow (12**36) and a constant a float reads as 0 refuse the float variant."""
    text = MOTOR.replace('w = "(Kt*i - b*w)/J"',
                         'w = "(Kt*i - b*w)/J + 1e-300*cosh(700*Ra) - 1e-300*sinh(700*Ra)"', 1)
    with pytest.raises(ModelFileError, match=r"cosh\(700\*Ra\) is 3\.21E\+364") as err:
        parse_model_text(text, source="m.toml")
    assert "dynamics.w" in str(err.value)
    from fdigen.backends.c.emit import check_float_range

    for term, says in (("1e-30*Vnom**(3*Vnom)", "beyond the range of a C float"),
                       ("1e-300*Vnom", "below the range of a C float")):
        m = parse_model_text(MOTOR.replace('w = "(Kt*i - b*w)/J"',
                                           f'w = "(Kt*i - b*w)/J + {term}"', 1),
                             source="m.toml")
        with pytest.raises(ModelFileError, match=says):
            check_float_range(m)
    check_float_range(parse_model_text(MOTOR, source="m.toml"))     # the shipped one


# ---------------------------------------------------------------- logs that expand
def _columns(n=200):
    t = np.arange(n) * 0.01
    return {"t": t, "u": np.sin(t), "w_tach": np.cos(t)}


def test_hdf5_reads_numeric_vectors_only(tmp_path, monkeypatch):
    """A dataset of sub-arrays or of long strings declared 10 values and took gigabytes."""
    h5py = pytest.importorskip("h5py")
    from fdigen.sim import log_tables

    path = tmp_path / "log.h5"
    with h5py.File(path, "w") as f:
        for k, v in _columns().items():
            f[k] = v
        f.create_dataset("junk", shape=(10,), dtype=np.dtype(("f8", (50, 50))))
        f.create_dataset("note", shape=(10,), dtype="S100000")
        f["matrix"] = np.zeros((20, 20))
    read = []
    original = h5py.Dataset.__getitem__
    monkeypatch.setattr(h5py.Dataset, "__getitem__",
                        lambda self, key: read.append(self.name) or original(self, key))
    cols = dict(log_tables.read_columns(path, path.read_bytes()))
    assert cols["junk"] is None and cols["note"] is None and cols["matrix"] is None
    assert sorted(read) == ["/t", "/u", "/w_tach"]
    assert np.allclose(cols["u"], _columns()["u"])


def test_mat_reads_columns_and_bounds_what_compressed_variables_expand_to(tmp_path,
                                                                          monkeypatch):
    scipy_io = pytest.importorskip("scipy.io")
    from fdigen.sim import log_tables

    cols = _columns()
    cell = np.empty((1, 3), dtype=object)
    for k in range(3):
        cell[0, k] = np.zeros((300, 300))
    bomb = tmp_path / "cell.mat"
    scipy_io.savemat(bomb, {**cols, "junk": cell}, do_compression=True)
    struct = tmp_path / "struct.mat"
    scipy_io.savemat(struct, {"log": {**cols, "junk": np.zeros((400, 400))}},
                     do_compression=True)
    good = tmp_path / "good.mat"
    scipy_io.savemat(good, {"log": cols}, do_compression=True)
    # 300 x 300 x 3 doubles compress to a few kB: past a limit of 100,000 values
    monkeypatch.setattr(log_tables, "MAX_VALUES", 100_000)
    for path in (bomb, struct):
        assert path.stat().st_size < 50_000
        with pytest.raises(LogError, match="once decompressed"):
            log_tables.read_columns(path, path.read_bytes())
    got = dict(log_tables.read_columns(good, good.read_bytes()))
    assert np.allclose(got["w_tach"], cols["w_tach"])
    # a cell below the limit is named, never read
    monkeypatch.setattr(log_tables, "MAX_VALUES", 32 * 1024 * 1024)
    got = dict(log_tables.read_columns(bomb, bomb.read_bytes()))
    assert got["junk"] is None and np.allclose(got["t"], cols["t"])


def test_parquet_reads_numeric_columns_only(tmp_path, monkeypatch):
    pa = pytest.importorskip("pyarrow")
    pq = pytest.importorskip("pyarrow.parquet")
    from fdigen.sim import log_tables

    cols = _columns()
    table = pa.table({**cols, "junk": pa.array([[0.0] * 1000] + [[]] * 199,
                                               type=pa.list_(pa.float64()))})
    path = tmp_path / "log.parquet"
    pq.write_table(table, path)
    asked = []
    original = pq.ParquetFile.iter_batches
    monkeypatch.setattr(pq.ParquetFile, "iter_batches",
                        lambda self, columns=None, **kw: asked.append(columns)
                        or original(self, columns=columns, **kw))
    got = dict(log_tables.read_columns(path, path.read_bytes()))
    assert asked == [["t", "u", "w_tach"]]
    assert got["junk"] is None and np.allclose(got["u"], cols["u"])
