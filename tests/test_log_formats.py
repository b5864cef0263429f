"""MAT (v5, v7.3: variables or a struct of columns), HDF5 and Parquet copies of a rig log
give the same log and the same diagnosis as the CSV; bad tables fail like bad CSV."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import RIG
from fdigen.errors import LogError
from fdigen.sim import log_tables
from fdigen.sim.log import read_log

LOG = RIG / "logs" / "fdi_leak_p.csv"
pytestmark = pytest.mark.skipif(not LOG.is_file(), reason=f"rig log {LOG} not available")

MAT73_HEADER = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created by fdigen tests HDF5 schema 1.00 ."


def columns_of(path):
    data = np.genfromtxt(path, delimiter=",", names=True)
    return {name: np.asarray(data[name], dtype=float) for name in data.dtype.names}


def write_mat73(path, columns, struct=None):
    """A MAT v7.3 file as MATLAB writes it: 512-byte header block, then HDF5, column
    vectors stored (1, N) with their MATLAB_class."""
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        where = f if struct is None else f.create_group(struct)
        if struct is not None:
            where.attrs["MATLAB_class"] = np.bytes_("struct")
        for name, values in columns.items():
            ds = where.create_dataset(name, data=values[None, :])
            ds.attrs["MATLAB_class"] = np.bytes_("double")
    with open(path, "r+b") as fh:
        fh.write(MAT73_HEADER.ljust(116) + b"\0" * 8 + b"\x00\x02IM")


def write_copies(folder, columns):
    import pyarrow as pa
    import pyarrow.parquet as pq
    import scipy.io

    paths = {}
    paths["v5"] = folder / "leak_v5.mat"
    scipy.io.savemat(paths["v5"], {k: v[:, None] for k, v in columns.items()})
    paths["v5_struct"] = folder / "leak_v5_struct.mat"
    scipy.io.savemat(paths["v5_struct"], {"rig": {k: v[:, None] for k, v in columns.items()}},
                     do_compression=True)
    paths["v73"] = folder / "leak_v73.mat"
    write_mat73(paths["v73"], columns)
    paths["v73_struct"] = folder / "leak_v73_struct.mat"
    write_mat73(paths["v73_struct"], columns, struct="rig")
    paths["hdf5"] = folder / "leak.h5"
    import h5py

    with h5py.File(paths["hdf5"], "w") as f:             # plain HDF5: 1-D datasets, a group
        group = f.create_group("cell3")
        for name, values in columns.items():
            group.create_dataset(name, data=values, compression="gzip")
    paths["parquet"] = folder / "leak.parquet"
    reordered = dict(reversed(list(columns.items())))     # columns matched by name
    pq.write_table(pa.table(reordered), paths["parquet"])
    return paths


@pytest.fixture(scope="module")
def copies(tmp_path_factory):
    return write_copies(tmp_path_factory.mktemp("formats"), columns_of(LOG))


def test_same_log(cylinder, copies):
    ref = read_log(LOG, cylinder, extra_columns=("xref",))
    for kind, path in copies.items():
        log = read_log(path, cylinder, sample_time=1e-3, extra_columns=("xref",))
        assert np.array_equal(log.t, ref.t), kind
        assert np.array_equal(log.u, ref.u) and np.array_equal(log.y, ref.y), kind
        assert set(log.extra) == {"xref"} and np.array_equal(log.extra["xref"],
                                                             ref.extra["xref"]), kind


def test_same_diagnosis(copies):
    from fdigen.cli import main

    def detect(path):
        res = CliRunner().invoke(main, ["detect", str(path), "--json"])
        assert res.exit_code == 0, (path, res.output)
        out = json.loads(res.output)
        out.pop("log")
        return out

    ref = detect(LOG)
    assert ref["diagnosis"]["fault"] == "pneumatic_or_actuator"
    for kind in ("v5_struct", "v73", "parquet"):
        assert detect(copies[kind]) == ref, kind


def test_bad_tables(cylinder, tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq
    import scipy.io

    cols = {k: v[:50] for k, v in columns_of(LOG).items()}
    cases = []
    missing = dict(cols)
    del missing["pn"]
    cases.append(("missing.mat", lambda p: scipy.io.savemat(p, missing), r"missing column 'pn'"))
    nan = {k: v.copy() for k, v in cols.items()}
    nan["x"][7] = np.nan
    cases.append(("nan.parquet", lambda p: pq.write_table(pa.table(nan), p),
                  r"row 8, column 'x': value is nan"))
    back = {k: v.copy() for k, v in cols.items()}
    back["t"][10] = back["t"][9]
    cases.append(("back.mat", lambda p: write_mat73(p, back), r"row 11, column 't': time does"))
    text = dict(cols, u=np.array(["a"] * 50))
    cases.append(("text.parquet", lambda p: pq.write_table(pa.table(text), p),
                  r"column 'u': not a numeric vector"))
    short = dict(cols, x=cols["x"][:40])
    cases.append(("short.mat", lambda p: scipy.io.savemat(p, short),
                  r"column 'x': 40 samples, column 't' has 50"))
    one = {k: v[:1] for k, v in cols.items()}
    cases.append(("one.parquet", lambda p: pq.write_table(pa.table(one), p), "single sample"))
    cases.append(("garbage.mat", lambda p: p.write_bytes(b"not a mat file" * 40),
                  "not a MAT v5/v7 or v7.3 file"))
    cases.append(("garbage.parquet", lambda p: p.write_bytes(b"PAR1 nope"),
                  "not a readable Parquet file"))
    for name, write, message in cases:
        path = tmp_path / name
        write(path)
        with pytest.raises(LogError, match=message) as info:
            read_log(path, cylinder)
        assert str(info.value).startswith(str(path)), info.value


def test_bounded(cylinder, tmp_path, monkeypatch):
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = {k: v[:1000] for k, v in columns_of(LOG).items()}
    path = tmp_path / "big.parquet"
    pq.write_table(pa.table(cols), path)
    monkeypatch.setattr(log_tables, "MAX_VALUES", 5000)     # declared size, before reading
    with pytest.raises(LogError, match=r"declares 7000 values, more than the 5000"):
        read_log(path, cylinder)
    with pytest.raises(LogError, match=r"MiB, more than"):
        read_log(path, cylinder, max_bytes=1000)             # the file size, as for a CSV
