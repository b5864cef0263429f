"""What a campaign builds once and reuses across its runs, and that reusing it changes no
number (issue 26: the cost of a run, not the numbers it gives).

- The plant step (the CasADi ``mapaccum`` of one sample: RK4 sub-steps, controllers) is
  keyed by the model without its ``[simulation]`` table and by the controllers' laws: the
  runs of a campaign, each with its own varied demand, share it; a controller gain that
  differs builds another.
- Designs are pickled (design cache, Dask workers) with sympy's ``Max``/``Min`` rebuilt as
  stored, without re-reducing their arguments: the same expressions.
"""

from __future__ import annotations

import dataclasses
import os
import pickle
from pathlib import Path

import numpy as np
import sympy as sp

from fdigen.model.model_file import load_model, parse_model_text
from fdigen.sim import plant as plant_module
from fdigen.sim.plant import simulate
from fdigen.tune.cases import simulate_case
from fdigen.tune.settings import Case


def _case(scale, shift, seed):
    return Case(kind="healthy", index=0, seed=seed, duration=2.0, parameters={},
                ref_scale=scale, ref_shift=shift)


def test_runs_with_varied_demands_share_one_plant_step_and_give_the_same_numbers():
    model = load_model("pneumatic_cylinder")
    cases = [_case(0.8, -0.1, 1), _case(1.2, 0.2, 2), _case(1.0, 0.0, 3)]
    plant_module._PLANT_CACHE.clear()
    shared = [simulate_case(model, c) for c in cases]
    assert len(plant_module._PLANT_CACHE) == 1          # one step for three demands
    alone = []
    for c in cases:                                     # each built on its own
        plant_module._PLANT_CACHE.clear()
        alone.append(simulate_case(model, c))
    for a, b in zip(shared, alone):
        assert np.array_equal(a.y, b.y) and np.array_equal(a.u, b.u)
        assert np.array_equal(a.x, b.x)
    # the demands did differ: the runs are not one run three times
    assert not np.array_equal(shared[0].ref, shared[1].ref)
    assert np.max(np.abs(shared[0].y - shared[1].y)) > 1e-3


def test_a_controller_law_that_differs_builds_its_own_plant_step():
    model = load_model("pneumatic_cylinder")
    sim = dict(model.simulation)
    plant_module._PLANT_CACHE.clear()
    base = simulate(model, 1.0, seed=4)
    changed = {**sim, "controller": sim["controller"].replace("40*", "20*")}
    assert changed != sim
    other = simulate(dataclasses.replace(model, simulation=changed), 1.0, seed=4)
    assert len(plant_module._PLANT_CACHE) == 2
    assert np.max(np.abs(base.u - other.u)) > 1e-6


def test_a_parameter_value_is_part_of_the_plant():
    path = Path(load_model("three_tank").source)
    text = path.read_text()
    line = 'az12 = { value = 0.5,'
    assert line in text
    a = parse_model_text(text, str(path))
    b = parse_model_text(text.replace(line, 'az12 = { value = 0.4,'), str(path))
    plant_module._PLANT_CACHE.clear()
    ra, rb = simulate(a, 50.0, seed=1), simulate(b, 50.0, seed=1)
    assert len(plant_module._PLANT_CACHE) == 2
    assert np.max(np.abs(ra.y - rb.y)) > 1e-4


def test_max_and_min_load_as_they_were_stored():
    from fdigen.design.stored_minmax import pickle_minmax_as_stored

    x, y, z = sp.symbols("x y z", real=True)
    exprs = [sp.Max(x, y + 1, sp.Min(z, 2)), sp.Min(x, 0), sp.Max(0.01, x * y) ** -1,
             sp.Max(x, sp.Max(y, z))]
    pickle_minmax_as_stored()
    for e in exprs:
        back = pickle.loads(pickle.dumps(e, protocol=pickle.HIGHEST_PROTOCOL))
        assert back == e and sp.srepr(back) == sp.srepr(e) and hash(back) == hash(e)
        assert type(back) is type(e)


def _runs(model, n):
    return [simulate_case(model, _case(0.8 + 0.1 * i, 0.05 * i, 10 + i)) for i in range(n)]


def _chunks(model):
    (run, _), = [v for v in plant_module._PLANT_CACHE.values()]
    return run


def test_a_plant_simulated_often_runs_compiled_with_the_same_numbers(tmp_path, monkeypatch):
    """From the third run the chunk function is compiled C; every run equals the virtual
    machine's bit for bit, and the library is reused by the next process (the cache)."""
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    model = load_model("pneumatic_cylinder")
    monkeypatch.setenv("FDIGEN_COMPILE_PLANT", "0")
    plant_module._PLANT_CACHE.clear()
    vm = _runs(model, 5)
    assert not _chunks(model).compiled
    monkeypatch.setenv("FDIGEN_COMPILE_PLANT", "1")
    plant_module._PLANT_CACHE.clear()
    native = _runs(model, 5)
    assert _chunks(model).compiled
    for a, b in zip(vm, native):
        assert np.array_equal(a.y, b.y) and np.array_equal(a.u, b.u)
        assert np.array_equal(a.x, b.x) and np.array_equal(a.not_real, b.not_real)
    libs = sorted((tmp_path / "cache").glob("plant_*.so"))
    assert len(libs) == 1 and libs[0].with_name(libs[0].name + ".sha256").is_file()
    # a second plant compiled in the same process (same exported names, its own library)
    other = dataclasses.replace(model, simulation={
        **model.simulation, "controller": model.simulation["controller"].replace("40*", "25*")})
    monkeypatch.setenv("FDIGEN_COMPILE_PLANT", "0")
    other_vm = _runs(other, 4)
    monkeypatch.setenv("FDIGEN_COMPILE_PLANT", "1")
    plant_module._PLANT_CACHE.clear()
    other_native = _runs(other, 4)
    assert _chunks(other).compiled
    assert len(list((tmp_path / "cache").glob("plant_*.so"))) == 2
    assert all(np.array_equal(a.y, b.y) for a, b in zip(other_vm, other_native))
    assert not np.array_equal(other_native[3].u, native[3].u)


def test_without_a_compiler_the_virtual_machine_runs(tmp_path, monkeypatch):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    model = load_model("three_tank")
    plant_module._PLANT_CACHE.clear()
    runs = [simulate(model, 30.0, seed=s) for s in range(4)]
    assert not _chunks(model).compiled
    monkeypatch.delenv("CC")
    plant_module._PLANT_CACHE.clear()
    again = [simulate(model, 30.0, seed=s) for s in range(4)]
    assert _chunks(model).compiled
    assert all(np.array_equal(a.y, b.y) for a, b in zip(runs, again))


def test_a_library_that_disagrees_is_never_used(tmp_path, monkeypatch):
    """A compiled chunk function that differs from the virtual machine (here: another
    plant's, standing in for a compiler that rounds otherwise) is dropped at its first
    chunk; that chunk and every later one are the virtual machine's."""
    from fdigen.sim import compiled_plant

    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    model = load_model("pneumatic_cylinder")
    other = dataclasses.replace(model, simulation={
        **model.simulation, "controller": model.simulation["controller"].replace("40*", "41*")})
    plant_module._PLANT_CACHE.clear()
    simulate(other, 0.5)
    (wrong, _), = plant_module._PLANT_CACHE.values()
    monkeypatch.setattr(compiled_plant, "compile_plant", lambda run: wrong.vm)
    plant_module._PLANT_CACHE.clear()
    monkeypatch.setenv("FDIGEN_COMPILE_PLANT", "0")
    vm = _runs(model, 4)
    monkeypatch.setenv("FDIGEN_COMPILE_PLANT", "1")
    plant_module._PLANT_CACHE.clear()
    runs = _runs(model, 4)
    assert not _chunks(model).compiled
    assert all(np.array_equal(a.y, b.y) for a, b in zip(vm, runs))


def test_a_cached_plant_library_that_was_replaced_is_compiled_again(tmp_path, monkeypatch,
                                                                     capsys):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path / "cache"))
    model = load_model("three_tank")
    plant_module._PLANT_CACHE.clear()
    first = [simulate(model, 30.0, seed=s) for s in range(3)]
    lib, = (tmp_path / "cache").glob("plant_*.so")
    forged = lib.with_name("forged.so")        # another file moved over it (a new inode:
    forged.write_bytes(lib.read_bytes()[:-16] + b"\0" * 16)   # this process has it mapped)
    os.replace(forged, lib)
    plant_module._PLANT_CACHE.clear()
    again = [simulate(model, 30.0, seed=s) for s in range(3)]
    assert "does not match the digest" in capsys.readouterr().err
    assert _chunks(model).compiled
    assert all(np.array_equal(a.y, b.y) for a, b in zip(first, again))
