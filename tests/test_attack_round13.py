"""Attack round 13 (tests/data/attack13): forged logs, a corrupted cache, a swapped
library, an interrupted commission, parameter bounds that divide by zero."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fdigen.cli import main

DATA = Path(__file__).parent / "data" / "attack13"


def _detect(path, *extra):
    return CliRunner().invoke(main, ["detect", str(path), "--model", "dc_motor", *extra])


def _varint(v: int) -> bytes:
    out = bytearray()
    while True:
        x, v = v & 0x7F, v >> 7
        out.append(x | 0x80 if v else x)
        if not v:
            return bytes(out)


def test_a_parquet_footer_that_lies_about_its_rows_is_refused_before_the_data(tmp_path):
    """The footer's ``num_rows`` rewritten to 1 over 4 x 4e7 constant doubles passed the
    size check and was read at 6.4 GB; here 4 x 2e5 rows, footer 1."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    n = 200_000
    col = pa.array(np.zeros(n))
    buf = io.BytesIO()
    pq.write_table(pa.table({"t": col, "u": col, "w": col, "i": col}), buf,
                   row_group_size=n, use_dictionary=True)
    raw = bytearray(buf.getvalue())
    flen = int.from_bytes(raw[-8:-4], "little")
    start = len(raw) - 8 - flen
    enc = _varint((n << 1) ^ (n >> 63))
    pos = raw.find(b"\x16" + enc, start)
    assert pos > 0
    raw[pos + 1:pos + 1 + len(enc)] = bytes([0x82] + [0x80] * (len(enc) - 2) + [0x00])
    lie = tmp_path / "lie.parquet"
    lie.write_bytes(bytes(raw))
    assert pq.ParquetFile(lie).metadata.num_rows == 1
    res = _detect(lie)
    assert res.exit_code == 2
    assert "footer declares 1 rows, its row groups 200000" in res.output


def test_mat_logs_a_duplicated_variable_and_a_v4_file_are_named():
    dup = _detect(DATA / "dupw.mat")
    assert dup.exit_code == 2 and "variable 'w' appears twice" in dup.output
    v4 = _detect(DATA / "v4.mat")
    assert v4.exit_code == 2 and "not a MAT v5/v7 or v7.3 file" in v4.output
    assert "33554432" not in v4.output


def test_hdf5_units_attributes_are_checked_like_a_units_row(tmp_path, motor):
    """``units = "mA"`` on the current was read as A: a healthy log ended in
    ``safety_stop``; the same data as CSV with its units row was refused."""
    import h5py

    from fdigen.sim.plant import simulate

    sim = simulate(motor, 2.0, seed=1)
    cols = sim.columns()

    def write(name, units, scale=None):
        path = tmp_path / name
        with h5py.File(path, "w") as f:
            for k, v in cols.items():
                d = f.create_dataset(k, data=np.asarray(v) * (scale or {}).get(k, 1.0))
                if k in units:
                    d.attrs["units"] = units[k]
        return path

    mA = _detect(write("mA.h5", {"i": "mA"}, {"i": 1000.0}))
    assert mA.exit_code == 2
    assert "column 'i' in 'mA', the model's is 'A'" in mA.output and "units attribute" in mA.output
    same = _detect(write("A.h5", {"i": "A"}), "--json")
    assert same.exit_code == 0, same.output
    ms = _detect(write("ms.h5", {"t": "ms"}, {"t": 1000.0}), "--json")
    assert ms.exit_code == 0, ms.output
    import json

    assert json.loads(ms.stdout)["flags"] == json.loads(same.stdout)["flags"]


def test_a_csv_log_of_more_rows_than_the_values_read_at_once_is_refused(tmp_path,
                                                                        monkeypatch):
    """255 MiB of short rows (33 million) took 156 s and 7.9 GB before their error: the
    rows are counted first, against the bound of the other formats."""
    import fdigen.sim.log as log

    monkeypatch.setattr(log, "MAX_VALUES", 1000)
    path = tmp_path / "rows.csv"
    path.write_text("t,u,w,i\n" + "".join(f"{k * 1e-3},0,0,0\n" for k in range(400)))
    res = _detect(path)
    assert res.exit_code == 2
    assert "rows of the" in res.output and "read into memory at once" in res.output


def test_simulate_names_the_format_it_writes(tmp_path):
    res = CliRunner().invoke(main, ["simulate", "--model", "dc_motor", "-o",
                                    str(tmp_path / "sim.mat")])
    assert res.exit_code == 2 and "writes its log as CSV text" in res.output
    assert not (tmp_path / "sim.mat").exists()


def test_parameter_bounds_that_divide_by_zero_are_said():
    res = CliRunner().invoke(main, ["inspect", "--model", str(DATA / "dc_La0.toml")])
    assert res.exit_code == 0, res.output
    assert "parameter La's bounds [0, 1] reach 0" in res.output


def test_verify_cuts_a_long_model_duration(motor):
    import dataclasses

    from fdigen.cli.durations import VERIFY_SAMPLES, verify_duration

    long = dataclasses.replace(motor, simulation={**motor.simulation, "duration": 10000.0})
    seconds, source = verify_duration(long, 1e-3, None)
    assert seconds == pytest.approx(VERIFY_SAMPLES * 1e-3) and "cut to" in source
    assert verify_duration(long, 1e-3, 10000.0)[0] == 10000.0      # asked for: kept


def test_a_corrupted_cache_entry_is_said_and_derived_again(tmp_path, monkeypatch, motor,
                                                           capsys):
    """One flipped byte of a cached design built C with a parameter of 1.15e-44 in place
    of 5e-4, and verify said "max rel 0 OK" (attack round 13)."""
    from fdigen.design import cache

    design = cache.cached_design(motor)
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "c"))
    cache.store_design(motor, design, {"what": "motor"})
    path = cache.design_path(motor)
    assert cache.load_design(motor) is not None
    assert cache.load_description(motor) == {"what": "motor"}
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0x01
    path.write_bytes(bytes(raw))
    assert cache.load_design(motor) is None
    assert "is corrupted" in capsys.readouterr().err
    cache.store_design(motor, design)          # a corrupted entry is written again
    assert cache.load_design(motor) is not None
    # another model's description under this key is not used
    from fdigen.model.model_file import load_model

    other = load_model("three_tank")
    desc = path.with_suffix(".json")
    import json

    desc.write_bytes(cache._framed(json.dumps(
        {"identity": list(cache._identity(other)), "description": {"what": "tanks"}})
        .encode()))
    assert cache.load_description(motor) is None


def test_a_swapped_casadi_library_is_compiled_again_and_never_called(tmp_path, motor):
    """Another design's library copied over the cached one: "double free or corruption",
    exit 134 (attack round 13)."""
    import shutil

    from fdigen.backends.casadi_backend.compiled import (NativeFunction, build_functions,
                                                         compile_library, function_names)
    from fdigen.design.cache import cached_design
    from fdigen.errors import BuildError
    from fdigen.model.model_file import load_model

    full = cached_design(motor)
    fewer = cached_design(load_model(DATA / "dc_noKi.toml"))
    assert len(fewer.residual_names) < len(full.residual_names)
    cache_dir = tmp_path / "cache"
    lib_full = compile_library(full, cache_dir)
    lib_fewer = compile_library(fewer, cache_dir)
    shutil.copyfile(lib_fewer, lib_full)                 # the swap
    again = compile_library(full, cache_dir)
    assert again == lib_full and again.read_bytes() != lib_fewer.read_bytes()
    name = function_names(full)["chunk"]
    with pytest.raises(BuildError, match="another design's"):
        NativeFunction(lib_fewer, function_names(fewer)["chunk"],
                       build_functions(full)["chunk"], f"{fewer.name}_casadi")
    NativeFunction(again, name, build_functions(full)["chunk"], f"{full.name}_casadi")


def test_an_interrupted_commission_leaves_a_refused_file(tmp_path, monkeypatch, motor):
    """Ctrl-C during the fault campaign left the final thresholds under a "Commissioned
    by" header with no refusal, and detect ran it in silence: the file now carries an
    "unfinished" refusal from its first write until the verdict replaces it."""
    import fdigen.tune as tune_pkg
    from fdigen.commission.pipeline import CommissionSettings, commission
    from fdigen.sim.log import write_log
    from fdigen.sim.plant import simulate

    log = tmp_path / "healthy.csv"
    write_log(log, simulate(motor, 4.0, seed=3).columns())

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(tune_pkg, "tune", stop)
    with pytest.raises(KeyboardInterrupt):
        commission(log, "dc_motor", out=tmp_path / "out", scheduler="synchronous",
                   build=False, settings=CommissionSettings(runs=2, duration=2.0,
                                                            validation_runs=1))
    written = tmp_path / "out" / "dc_motor_commissioned.toml"
    assert 'refused = "fdigen commission: unfinished' in written.read_text()
    res = CliRunner().invoke(main, ["detect", str(log), "--model", str(written)])
    assert "REFUSED by `fdigen commission`" in res.output and "unfinished" in res.output
