"""The CasADi backend against the sympy reference: converter, core, full step, logs, build.

Relative differences of continuous outputs are measured as in
:mod:`fdigen.verify.equivalence`: ``|a - b| / max(|b|, s)`` with ``s`` the largest
magnitude of that output over the compared samples, so that a residual crossing zero is
judged on its own scale.
"""

from __future__ import annotations

import os
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import sympy as sp

from fdigen.backends.casadi_backend import compiled as compiled_mod
from fdigen.backends.casadi_backend.compiled import (casadi_sources, compile_library,
                                                     function_names)
from fdigen.backends.casadi_backend.convert import sympy_to_casadi
from fdigen.backends.casadi_backend.functions import model_functions, state_layout
from fdigen.backends.casadi_backend.log_functions import step_function, whole_log_function
from fdigen.backends.casadi_backend.runner import CasadiFdi
from fdigen.backends.reference import ReferenceFdi
from fdigen.design.fdi_design import fdi_design
from fdigen.errors import BuildError
from fdigen.model.model_file import load_model

LOG = Path(__file__).resolve().parents[2] / "shared" / "rig" / "logs" / "fdi_leak_p.csv"
if not LOG.is_file():  # CI clones main with shared/ beside it
    LOG = Path(__file__).resolve().parents[1] / ".." / "shared" / "rig" / "logs" / LOG.name

X, Y = sp.symbols("x y", real=True)


# -- fixtures ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def design():
    return fdi_design(load_model())


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("fdigen-cache")


@pytest.fixture(scope="module")
def interpreted(design):
    return CasadiFdi(design, compiled=False)


@pytest.fixture(scope="module")
def compiled(design, cache):
    return CasadiFdi(design, compiled=True, cache_dir=cache)


@pytest.fixture(scope="module")
def leak_log():
    if not LOG.is_file():
        pytest.skip(f"reference rig log {LOG} not available")
    data = np.genfromtxt(LOG, delimiter=",", names=True)
    u = data["u"][:, None]
    y = np.stack([data["x"], data["x2"], data["pp"], data["pn"]], axis=1)
    return u, y


@pytest.fixture(scope="module")
def leak_reference(design, leak_log):
    return ReferenceFdi(design).run(*leak_log)


def _assert_rel(got, want, rtol, what=""):
    got, want = np.atleast_2d(np.asarray(got, float)), np.atleast_2d(np.asarray(want, float))
    assert got.shape == want.shape, what
    scale = np.maximum(np.abs(want), np.max(np.abs(want), axis=0, keepdims=True))
    diff = np.abs(got - want)
    rel = np.where(diff == 0, 0.0, diff / np.where(scale > 0, scale, np.inf))
    assert np.all(np.isfinite(got) == np.isfinite(want)), what
    assert np.nanmax(rel, initial=0.0) <= rtol, f"{what}: max relative difference {rel.max()}"


def _assert_same_run(got, want, rtol):
    assert set(got) == set(want)
    for key in want:
        assert got[key].shape == want[key].shape, key
        assert got[key].dtype == want[key].dtype, key
    for key in ("flags", "fault_class", "action"):
        np.testing.assert_array_equal(got[key], want[key], err_msg=key)
    for key in ("r", "rms", "aux"):
        _assert_rel(got[key], want[key], rtol, key)


# -- converter --------------------------------------------------------------------------
CONVERTER_TABLE = [
    X + Y, X - 2 * Y, X * Y / 3, X / Y, -X * Y / (X + Y), 2.5 * X * Y - 0.125 / X,
    X ** 2, X ** 3, X ** -2, 1 / X, sp.sqrt(X), 1 / sp.sqrt(X), X ** sp.Rational(3, 2),
    X ** sp.Rational(-1, 3), X ** 2.5, X ** Y, sp.Rational(1, 3) * X, sp.pi * X + sp.E,
    sp.exp(X), sp.log(X), sp.sin(X), sp.cos(X), sp.tan(X), sp.asin(X / 4), sp.acos(X / 4),
    sp.atan(X), sp.atan2(Y - 1, X - 1), sp.sinh(X), sp.cosh(X), sp.tanh(X),
    sp.Abs(X - Y), sp.sign(X - Y), sp.Min(X, Y), sp.Max(X, Y, 1.5), sp.Min(X, Y, 1.0) + 1,
    sp.Piecewise((X, X > Y), (Y ** 2, X < 1), (0, True)),
    sp.Piecewise((X - Y, X >= 2)),  # nan where no condition holds
    sp.StrictLessThan(X, Y), sp.LessThan(X, Y), sp.Eq(X, Y), sp.Ne(X, Y),
    sp.GreaterThan(X, Y), sp.StrictGreaterThan(X, 2),
    sp.Piecewise((1.0, sp.And(X > 1, Y < 2)), (2.0, sp.Or(X < 0.8, sp.Not(Y < 2))),
                 (3.0, True)),
]


def _sympy_value(expr, a, b):
    v = expr.subs({X: sp.Float(a, 30), Y: sp.Float(b, 30)})
    if v in (sp.true, sp.false):
        return 1.0 if v == sp.true else 0.0
    v = sp.N(v, 30)
    return float("nan") if v == sp.nan else float(v)


@pytest.mark.parametrize("expr", CONVERTER_TABLE, ids=str)
def test_converter_matches_sympy(expr):
    xs, ys = ca.SX.sym("x"), ca.SX.sym("y")
    fn = ca.Function("f", [xs, ys], [sympy_to_casadi(expr, {X: xs, Y: ys})])
    rng = np.random.default_rng(7)
    pts = list(zip(rng.uniform(0.5, 3.0, 12), rng.uniform(0.5, 3.0, 12)))
    pts += [(2.0, 2.0), (0.75, 2.5), (2.5, 0.75), (1.25, 1.75)]
    got = np.array([float(fn(a, b)) for a, b in pts])
    want = np.array([_sympy_value(expr, a, b) for a, b in pts])
    np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-15, equal_nan=True,
                               err_msg=str(expr))


def test_converter_follows_the_reference_printer_bit_for_bit():
    """Sums and products are associated like the numpy printer of the reference."""
    syms = sp.symbols("a0:6", real=True)
    rng = np.random.default_rng(3)
    exprs = []
    for _ in range(20):
        terms = []
        for _ in range(5):
            i, j, k = rng.integers(0, 6, 3)
            c = sp.Float(float(rng.normal()), 17)
            terms.append(c * syms[i] * syms[j] / (syms[k] + 1.5))
        exprs.append(sp.Add(*terms) ** 2 - 1 / (1 + sp.Add(*terms[:2]) ** 2)
                     + sp.sqrt(syms[0] * syms[1]))
    vals = rng.uniform(0.5, 2.0, (6, 500))
    sx = ca.SX.sym("a", 6)
    mapping = dict(zip(syms, [sx[i] for i in range(6)]))
    fn = ca.Function("f", [sx], [ca.vertcat(*[sympy_to_casadi(e, mapping) for e in exprs])])
    got = np.array(fn(vals))
    want = np.array(sp.lambdify([syms], exprs, "numpy")(list(vals)))
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("expr, name", [(sp.floor(X), "floor"), (sp.gamma(X) + Y, "gamma"),
                                        (sp.besselj(1, X), "besselj"),
                                        (sp.Function("mystery")(X), "mystery")])
def test_unsupported_function_is_named(expr, name):
    with pytest.raises(BuildError, match=f"unsupported function '{name}'"):
        sympy_to_casadi(expr, {X: ca.SX.sym("x"), Y: ca.SX.sym("y")})


def test_unsupported_node_and_unknown_symbol():
    with pytest.raises(BuildError, match="ImaginaryUnit|not a real number"):
        sympy_to_casadi(sp.I * X, {X: ca.SX.sym("x")})
    with pytest.raises(BuildError, match="symbol 'y'"):
        sympy_to_casadi(X + Y, {X: ca.SX.sym("x")})


def test_converter_memoises_subexpressions():
    xs = ca.SX.sym("x")
    memo = {}
    shared = sp.sin(X) + sp.exp(X)
    a = sympy_to_casadi(sp.cos(shared), {X: xs}, memo=memo)
    b = sympy_to_casadi(sp.tan(shared), {X: xs}, memo=memo)
    assert shared in memo
    assert ca.is_equal(a.dep(0), b.dep(0))          # one node, not two equal ones
    fn = ca.Function("f", [xs], [a, b])
    assert fn.n_instructions() == 8   # input, sin, exp, +, cos, tan, two outputs


# -- model functions ----------------------------------------------------------------------
def test_model_functions(design):
    model = design.model
    fns = model_functions(model)
    assert set(fns) == {"f", "A", "B", "h", "C"}
    rng = np.random.default_rng(5)
    p = [q.value for q in model.parameters]
    f_ref = sp.lambdify([list(model.x), list(model.u), list(model.p)],
                        [model.f(), model.f().jacobian(model.x), model.f().jacobian(model.u),
                         model.h(), model.h().jacobian(model.x)], "numpy")
    for _ in range(20):
        x = [rng.uniform(*s.range) for s in model.states]
        u = [rng.uniform(*s.range) for s in model.inputs]
        for key, want in zip("fABhC", f_ref(x, u, p)):
            np.testing.assert_allclose(np.array(fns[key](x, u, p)),
                                       np.array(want, dtype=float).reshape(
                                           np.array(fns[key](x, u, p)).shape),
                                       rtol=1e-12, atol=1e-12 * np.max(np.abs(want)), err_msg=key)


# -- core --------------------------------------------------------------------------------
def random_points(design, n, seed):
    """States/inputs over their ranges, outputs ``h(x) + noise``, FDI states near the
    initial state of a random sample, random modes. Arrays are (length, n)."""
    model = design.model
    rng = np.random.default_rng(seed)
    ref = ReferenceFdi(design)
    h = sp.lambdify([list(model.x), list(model.u), list(model.p)], list(model.h()), "numpy")

    def outputs(x, u):
        y = np.array([np.broadcast_to(np.asarray(v, float), (n,))
                      for v in h(list(x), list(u), list(ref.p))])
        big = np.where(rng.random(n) < 0.2, 30.0, 1.0)   # sometimes a far-off sensor
        return y + rng.standard_normal(y.shape) * big * np.array(
            [o.noise_std for o in model.outputs])[:, None]

    x = np.array([rng.uniform(*s.range, n) for s in model.states])
    u = np.array([rng.uniform(*s.range, n) for s in model.inputs])
    y = outputs(x, u)
    (z0,) = ref.init_fn(list(u), list(y), list(ref.p))
    z = np.array([np.broadcast_to(np.asarray(v, float), (n,)) for v in z0])
    widths = {s.name: s.range[1] - s.range[0] for s in model.states}
    for i, name in enumerate(design.state_names):
        width = widths.get(name.split("_", 1)[-1])
        if width is None:
            width = 4 * np.std(z[i]) or 1.0
        z[i] = z[i] + 0.05 * width * rng.standard_normal(n)
    mode = rng.integers(0, 2, (2, n)).astype(float)
    return z, u, y, mode


@pytest.fixture(scope="module")
def points(design):
    z, u, y, mode = random_points(design, 1000, seed=11)
    ref = ReferenceFdi(design)
    want = [np.array([ref.core(z[:, k], u[:, k], y[:, k], mode[:, k])[j]
                      for k in range(z.shape[1])]) for j in range(3)]
    return (z, u, y, mode), want


@pytest.mark.parametrize("backend", ["interpreted", "compiled"])
def test_core_matches_reference(backend, points, request):
    fdi = request.getfixturevalue(backend)
    (z, u, y, mode), want = points
    got = fdi.core(z, u, y, mode)                          # all points at once
    for g, w, name in zip(got, want, ("z_next", "r", "aux")):
        assert g.shape == w.T.shape
        _assert_rel(g.T, w, 1e-12, f"{backend} {name}")
    one = fdi.core(z[:, 0], u[:, 0], y[:, 0], mode[:, 0])  # one point: 1-D results
    for g, w in zip(one, want):
        assert g.ndim == 1
        _assert_rel(g[None, :], w[:1], 1e-12)


def test_core_with_parameter_overrides(design, points):
    (z, u, y, mode), _ = points
    params = {"Ff": 130.0, "K": 1.2e-3}
    ref = ReferenceFdi(design, parameters=params)
    fdi = CasadiFdi(design, parameters=params)
    for k in range(5):
        for g, w in zip(fdi.core(z[:, k], u[:, k], y[:, k], mode[:, k]),
                        ref.core(z[:, k], u[:, k], y[:, k], mode[:, k])):
            _assert_rel(g[None, :], w[None, :], 1e-12)


# -- whole step and logs ------------------------------------------------------------------
@pytest.mark.parametrize("backend", ["interpreted", "compiled"])
def test_run_matches_reference_on_rig_log(backend, request, leak_log, leak_reference):
    fdi = request.getfixturevalue(backend)
    got = fdi.run(*leak_log)
    _assert_same_run(got, leak_reference, 1e-9)
    # coverage of the comparison: flags rise (realignment frozen) and a class is isolated
    assert leak_reference["flags"].max() > 0 and leak_reference["fault_class"].max() > 0


def test_run_with_accommodation(design, interpreted, compiled, leak_log):
    """A redundant position sensor offset: isolated, action ``accommodate`` (mode 1)."""
    u, y = leak_log[0][:4000].copy(), leak_log[1][:4000].copy()
    y[1500:, 1] += 2e-3
    want = ReferenceFdi(design).run(u, y)
    for fdi in (interpreted, compiled):
        _assert_same_run(fdi.run(u, y), want, 1e-9)
    assert 1 in want["action"]   # coverage: the accommodate branch of the mode was taken


def test_shift_register_equals_reference_ring_buffer(design, interpreted, leak_log):
    K = 1537   # not a multiple of the window nor of the chunk length
    u, y = leak_log[0][:K], leak_log[1][:K]
    ref = ReferenceFdi(design)
    ref.run(u, y)
    interpreted.run(u, y)
    s, lay = interpreted.state, state_layout(design)
    st, N, nr = ref.state, design.evaluation.window, len(design.residual_names)
    ring = np.roll(st.buffer, -st.index, axis=0)        # oldest sample first
    np.testing.assert_array_equal(s[lay["buffer"]].reshape(N, nr), ring)
    _assert_rel(s[lay["sums"]][None, :], st.sums[None, :], 1e-9, "sums")
    flags = s[lay["flags"]]
    assert set(flags) <= {0.0, 1.0}
    assert int(sum(int(b) << i for i, b in enumerate(flags))) == st.flags
    for name in ("candidate", "count", "decision"):
        assert s[lay[name]][0] == getattr(st, name), name
    assert s[lay["initialised"]][0] == 1.0
    _assert_rel(s[lay["z"]][None, :], ref.z[None, :], 1e-9, "z")


def test_step_by_step_pure_sx_and_mapaccum_agree(design, interpreted, leak_log):
    """MX step (block copies), pure-SX step, ``step()`` and ``mapaccum``: same bits."""
    K = 230   # past one window
    u, y = leak_log[0][:K], leak_log[1][:K]
    out = interpreted.run(u, y)
    pure = step_function(design, pure_sx=True)
    assert pure.is_a("SXFunction")
    s_pure = np.zeros(state_layout(design)["size"].stop)
    interpreted.reset()
    for k in range(K):
        res = interpreted.step(u[k], y[k])
        o = pure(s_pure, u[k], y[k], interpreted.p)
        s_pure = np.array(o[0]).ravel()
        np.testing.assert_array_equal(s_pure, interpreted.state)
        for key, j in (("r", 1), ("rms", 2), ("aux", 6)):
            np.testing.assert_array_equal(res[key], out[key][k])
            np.testing.assert_array_equal(np.array(o[j]).ravel(), out[key][k])
        for key, j in (("flags", 3), ("fault_class", 4), ("action", 5)):
            assert res[key] == out[key][k] == int(o[j])
    F = whole_log_function(design, 40)
    traj, r, rms = F(np.zeros(len(s_pure)), u[:40].T, y[:40].T, interpreted.p)[:3]
    np.testing.assert_array_equal(np.array(r).T, out["r"][:40])
    np.testing.assert_array_equal(np.array(rms).T, out["rms"][:40])
    interpreted.run(u[:40], y[:40])
    np.testing.assert_array_equal(np.array(traj)[:, -1], interpreted.state)


def test_compiled_chunks_equal_the_shift_register_step(design, compiled, leak_log):
    """The compiled run (window outside the recursion, chunks called in place) gives the
    bits of the shift-register step chained sample by sample, and the same final
    extended state (window buffer included), across chunk boundaries and a partial last
    chunk; flags and a class are raised on the way."""
    K = 3 * compiled.chunk_length + 37
    assert compiled.chunk_length <= design.evaluation.window
    u, y = leak_log[0][2000:2000 + K], leak_log[1][2000:2000 + K]
    got = compiled.run(u, y)
    step = compiled.functions["step"]
    s = np.zeros(state_layout(design)["size"].stop)
    cols = {k: [] for k in ("r", "rms", "flags", "fault_class", "action", "aux")}
    for k in range(K):
        o = step(s, u[k], y[k], compiled.p)
        s = np.array(o[0]).ravel()
        for key, v in zip(cols, o[1:]):
            cols[key].append(np.array(v).ravel())
    for key, v in cols.items():
        want = np.array(v)
        want = want if key in ("r", "rms", "aux") else np.rint(want[:, 0]).astype(np.int64)
        np.testing.assert_array_equal(got[key], want, err_msg=key)
    np.testing.assert_array_equal(compiled.state, s)
    assert got["flags"].max() > 0


def test_run_of_empty_and_short_logs(interpreted):
    out = interpreted.run(np.zeros((0, 1)), np.zeros((0, 4)))
    assert out["r"].shape == (0, interpreted.functions["core"].size1_out(1))
    assert out["flags"].dtype == np.int64 and out["flags"].shape == (0,)


# -- generated C and the library cache ------------------------------------------------------
def test_casadi_sources_are_deterministic(design):
    first = casadi_sources(design)
    second = casadi_sources(design)
    assert first == second
    assert set(first) == {f"{design.name}_casadi.c", f"{design.name}_casadi.h"}
    c = first[f"{design.name}_casadi.c"]
    assert c.startswith("// Generated by fdigen")
    assert "template: casadi/source.c.j2" in c
    for name in function_names(design).values():
        assert f"int {name}(" in c


def test_second_compile_hits_the_cache(design, compiled, cache, monkeypatch):
    lib = compile_library(design, cache)   # compiled by the ``compiled`` fixture
    before = lib.stat()
    calls = []
    real = compiled_mod._start_compiler
    monkeypatch.setattr(compiled_mod, "_start_compiler",
                        lambda cmd: calls.append(cmd) or real(cmd))
    again = compile_library(design, cache)
    after = again.stat()
    assert again == lib
    assert calls == []
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)
    # the counter does see a build into an empty cache
    fresh = cache / "fresh"
    built = compile_library(design, fresh)
    assert len(calls) == 1 and built.name == lib.name
    # no temporaries: the source, the library and the library's digest
    assert sorted(p.suffix for p in fresh.iterdir()) == [".c", ".sha256", ".so"]


def test_compiler_failure_raises_build_error(design, tmp_path):
    fake = tmp_path / "fakecc"
    fake.write_text("#!/bin/sh\necho 'fakecc: error: no luck today' >&2\nexit 3\n")
    fake.chmod(0o755)
    with pytest.raises(BuildError, match="no luck today"):
        compile_library(design, tmp_path / "cache", compiler=str(fake))
    assert not any((tmp_path / "cache").glob("*.so"))
    with pytest.raises(BuildError, match="not found"):
        compile_library(design, tmp_path / "cache", compiler="no-such-cc-fdigen")


def test_default_cache_folder(monkeypatch, tmp_path):
    monkeypatch.setenv("FDIGEN_CACHE", str(tmp_path))
    assert compiled_mod.default_cache_dir() == tmp_path
    monkeypatch.delenv("FDIGEN_CACHE")
    assert compiled_mod.default_cache_dir() == Path(os.path.expanduser("~")) / ".cache" / "fdigen"
