"""Attack round 14: the compiled plants, the cache folder, units of ratios, validation logs.

- A cached plant library is read only through a descriptor of a cache folder of the
  user's own that no one else can write, verified against its digest, and loaded from a
  private copy: a planted library (another user's folder swapped in after the check had
  run inside the victim's process) is never loaded.
- A compile is bounded: a source over the size limit is not compiled (7.1 MB at 1000
  sub-steps had run gcc past 10 minutes, per process), a compiler past its time limit is
  killed with its whole process group (its cc1 had run on as an orphan), and a failure is
  not tried again in the process.
- ``FDIGEN_CACHE`` is one absolute folder for every cache (``~`` expanded; a relative
  ``-oops`` reached gcc as an option; ``~nosuchuser`` was an internal error).
- ``FDIGEN_COMPILE_PLANT`` takes 0, false, no, off; the agreement check is bit for bit.
- Ratios: ``-`` against ``%`` is a scale (100x), ``%`` and ``percent`` are one unit.
- A validation log needs one RMS window past the start-up to validate anything.
"""

from __future__ import annotations

import os
import stat
import time
from pathlib import Path

import numpy as np
import pytest

from fdigen.model.model_file import load_model
from fdigen.sim import compiled_plant
from fdigen.sim import plant as plant_module
from fdigen.sim.plant import simulate


def _three(model, **kw):
    return [simulate(model, 20.0, seed=s, **kw) for s in range(3)]


def _chunks():
    (run, _), = plant_module._PLANT_CACHE.values()
    return run


@pytest.fixture(autouse=True)
def _fresh(monkeypatch):
    plant_module._PLANT_CACHE.clear()
    compiled_plant._FAILED.clear()
    monkeypatch.delenv("FDIGEN_COMPILE_PLANT", raising=False)
    yield
    plant_module._PLANT_CACHE.clear()
    compiled_plant._FAILED.clear()


def _plant_run(model):
    plant_module._PLANT_CACHE.clear()
    simulate(model, 1.0)
    return _chunks().vm


@pytest.mark.skipif(os.getuid() != 0, reason="chown to another user needs root")
def test_a_library_in_a_cache_folder_of_another_user_is_never_loaded(tmp_path, monkeypatch):
    model = load_model("three_tank")
    cache = tmp_path / "cache"
    monkeypatch.setenv("FDIGEN_CACHE", str(cache))
    vm = _three(model)                       # compiled (third run) and stored: ours
    lib, = cache.glob("plant_*.so")
    # the attacker's library under the same name, with its own digest, in a folder the
    # attacker owns (the victim's folder swapped for it)
    other = load_model("dc_motor")
    fake = compiled_plant._compile_private(compiled_plant.plant_source(_plant_run(other)),
                                           "gcc")
    plant_module._PLANT_CACHE.clear()
    assert fake is not None
    lib.write_bytes(fake)
    import hashlib
    lib.with_name(lib.name + ".sha256").write_text(hashlib.sha256(fake).hexdigest() + "\n")
    os.chown(cache, 65534, 65534)
    assert compiled_plant._read_trusted(cache, lib.name) is None
    os.chown(cache, 0, 0)
    cache.chmod(0o777)                       # writable by others: not read either
    assert compiled_plant._read_trusted(cache, lib.name) is None
    cache.chmod(0o700)
    link = tmp_path / "link"
    link.symlink_to(cache)                   # a link: not followed
    assert compiled_plant._read_trusted(link, lib.name) is None
    # the simulation never runs the planted library: compiled privately, same numbers
    os.chown(cache, 65534, 65534)
    plant_module._PLANT_CACHE.clear()
    again = _three(model)
    assert _chunks().compiled
    assert all(np.array_equal(a.y, b.y) for a, b in zip(vm, again))
    assert lib.read_bytes() == fake          # and the folder not ours is not written


def test_a_source_over_the_size_limit_is_not_compiled(tmp_path, monkeypatch):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(compiled_plant, "MAX_PLANT_SOURCE", 1000)
    runs = _three(load_model("three_tank"))
    assert not _chunks().compiled and runs[2].y.shape[0] > 0
    assert not list((tmp_path / "cache").glob("plant_*.so"))


def test_a_compiler_that_hangs_is_killed_with_its_children(tmp_path, monkeypatch):
    pids = tmp_path / "pids"
    cc = tmp_path / "hangcc"
    cc.write_text(f"#!/bin/sh\necho $$ >> {pids}\nsleep 300 &\necho $! >> {pids}\nwait\n")
    cc.chmod(cc.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", str(cc))
    from fdigen.backends.casadi_backend import compiled as cc_module

    monkeypatch.setattr(compiled_plant, "COMPILE_TIMEOUT", 1.0)
    monkeypatch.setattr(cc_module, "VERSION_TIMEOUT", 1.0)
    model = load_model("three_tank")
    runs = _three(model) + _three(model)     # the failure is not tried again
    assert not _chunks().compiled and len(runs) == 6
    # `--version` once (the cache key) and one compile: each a shell and its child
    assert pids.read_text().count("\n") == 4
    time.sleep(0.2)
    for pid in map(int, pids.read_text().split()):
        try:
            os.kill(pid, 0)
            alive = Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
        except ProcessLookupError:
            alive = False
        assert not alive, pid


@pytest.mark.parametrize("value", ["0", "false", "No", " off "])
def test_the_switch_keeps_the_virtual_machine(tmp_path, monkeypatch, value):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("FDIGEN_COMPILE_PLANT", value)
    _three(load_model("three_tank"))
    assert not _chunks().compiled


def test_the_agreement_is_bit_for_bit():
    a = [np.array([0.0, 1.0])]
    assert compiled_plant._same(a, [np.array([0.0, 1.0])])
    assert not compiled_plant._same(a, [np.array([-0.0, 1.0])])


def test_one_cache_folder_absolute_with_home_expanded(tmp_path, monkeypatch):
    from fdigen.backends.casadi_backend.compiled import default_cache_dir
    from fdigen.design.cache import cache_dir
    from fdigen.files.cache_root import cache_root
    from fdigen.library_log import log_path

    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv("FDIGEN_CACHE", "~/fdc")
    assert cache_root() == tmp_path / "fdc" == default_cache_dir()
    assert cache_dir() == tmp_path / "fdc" / "designs"
    assert log_path().parent == tmp_path / "fdc"
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("FDIGEN_CACHE", "-oops")
    assert cache_root() == tmp_path / "-oops" and cache_root().is_absolute()
    monkeypatch.setenv("FDIGEN_CACHE", "~nosuchuser_fdigen/x")
    assert cache_root().is_absolute()
    runs = _three(load_model("three_tank"))     # no internal error: simulated
    assert len(runs) == 3


@pytest.mark.parametrize("model_unit, logged, refused", [
    ("-", "%", True), ("-", "ppm", True), ("%", "permille", True),
    ("%", "percent", False), ("percent", "%", False), ("1", "-", False)])
def test_ratios_in_their_scales(tmp_path, model_unit, logged, refused):
    from fdigen.errors import LogError
    from fdigen.sim.log_units import check_units_row

    model = load_model(Path(__file__).parent / "data" / "newuser54" / "boiler.toml")
    import dataclasses

    inputs = tuple(dataclasses.replace(v, unit=model_unit) if v.name == "u" else v
                   for v in model.inputs)
    model = dataclasses.replace(model, inputs=inputs)
    units = {"u": logged}
    if refused:
        with pytest.raises(LogError, match="column 'u'"):
            check_units_row(tmp_path / "log.csv", model, 2, units)
    else:
        assert check_units_row(tmp_path / "log.csv", model, 2, units) == 1.0


def test_a_validation_log_one_sample_past_the_start_up_validates_nothing(tmp_path):
    from fdigen.commission.validation_logs import check_validation_logs

    data = Path(__file__).parent / "data" / "newuser54"
    model = load_model(data / "eboiler_commissioned.toml")
    lines = (data / "healthy_B.csv").read_text().splitlines()
    window = int(model.fdi["window"])
    samples = {}
    for n in (81, 80 + window, 81 + window):     # start-up 400 s at 5 s: 80 samples
        path = tmp_path / f"v{n}.csv"
        path.write_text("\n".join(lines[:2 + n]) + "\n")
        checked, = check_validation_logs(model, [path])
        samples[n] = checked["validates"]
    assert samples == {81: False, 80 + window: True, 81 + window: True}


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
@pytest.mark.parametrize("args", [["--help"], ["--version"], ["inspect", "--help"]])
def test_help_into_a_full_output_is_one_error_line(args):
    """`fdigen --help > /dev/full` printed a traceback (exit 1): the help is printed while
    the command line is parsed, before the command's own error handling."""
    import subprocess
    import sys

    with open("/dev/full", "w") as full:
        proc = subprocess.run([sys.executable, "-m", "fdigen", *args], stdout=full,
                              stderr=subprocess.PIPE, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "fdigen: error: cannot write to standard output (No space left on device)"]
