"""Each derivation against an independent computation (hand algebra, SciPy, python-control)."""

import control
import numpy as np
import pytest
import scipy.integrate
import scipy.linalg
import scipy.signal
import sympy as sp

from fdigen.derive.kalman import continuous_kalman_gain, discrete_kalman_gain
from fdigen.derive.linearisation import (discretise_noise, discretise_zoh, linearise,
                                         symbolic_jacobians)
from fdigen.derive.observability import observability_rank, observable_reduction
from fdigen.errors import DesignError


def _numeric_f(model):
    f = sp.lambdify([list(model.x), list(model.u)], list(model.f().subs(model.parameter_values)))
    return lambda x, u: np.array(f(list(x), list(u)), dtype=float)


def test_jacobians_match_central_differences(cylinder):
    f = _numeric_f(cylinder)
    rng = np.random.default_rng(0)
    for _ in range(5):
        x = np.array([rng.uniform(*s.range) for s in cylinder.states])
        u = np.array([rng.uniform(*s.range) for s in cylinder.inputs])
        op = {s.name: x[i] for i, s in enumerate(cylinder.states)}
        op.update({s.name: u[i] for i, s in enumerate(cylinder.inputs)})
        lin = linearise(cylinder, op)
        A_fd = np.empty((4, 4))
        for j in range(4):
            h = 1e-6 * max(abs(x[j]), 1e-3)
            e = np.zeros(4)
            e[j] = h
            A_fd[:, j] = (f(x + e, u) - f(x - e, u)) / (2 * h)
        hu = 1e-6
        B_fd = ((f(x, u + hu) - f(x, u - hu)) / (2 * hu))[:, None]
        np.testing.assert_allclose(lin.A, A_fd, rtol=1e-6, atol=1e-6 * np.abs(A_fd).max())
        np.testing.assert_allclose(lin.B, B_fd, rtol=1e-6)


def test_fault_matrices(cylinder):
    jac = symbolic_jacobians(cylinder)
    names = [f.name for f in cylinder.faults]
    Vp = sp.Symbol("V0", real=True) + sp.Symbol("A", real=True) * sp.Symbol("x", real=True)
    g, R, Ts, Pp, Patm, K, v = sp.symbols("gamma R Ts Pp Patm K v", real=True)
    # leak_p enters dPp/dt as -gamma R Ts / Vp (Pp - Patm)
    assert sp.simplify(jac.E[0, names.index("leak_p")] + g * R * Ts / Vp * (Pp - Patm)) == 0
    # the valve fault scales the input: df/dvalve = B v
    col = jac.E[:, names.index("valve")]
    assert sp.simplify(col - jac.B * v) == sp.zeros(4, 1)
    # a sensor fault enters only its own output
    F = jac.F
    k = names.index("pressure_sensor_p")
    assert list(F[:, k]) == [0, 0, 1, 0]


def test_zoh_matches_scipy(cylinder):
    lin = linearise(cylinder)
    dt = 1e-3
    disc = discretise_zoh(lin, dt)
    Ad, Bd, *_ = scipy.signal.cont2discrete((lin.A, lin.B, lin.C, lin.D), dt, method="zoh")
    np.testing.assert_allclose(disc.A, Ad, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(disc.B, Bd, rtol=1e-10)


def test_noise_discretisation_matches_quadrature(cylinder):
    red = observable_reduction(cylinder, ("x3",))
    A = red.A_num
    Qc = np.diag([1e6, 1e-10, 1e-2])
    dt = 1e-3
    Qd = discretise_noise(A, Qc, dt)

    def integrand(s, i, j):
        E = scipy.linalg.expm(A * s)
        return (E @ Qc @ E.T)[i, j]

    for i in range(3):
        for j in range(3):
            ref = scipy.integrate.quad(integrand, 0, dt, args=(i, j), epsabs=0, epsrel=1e-10)[0]
            assert Qd[i, j] == pytest.approx(ref, rel=1e-7, abs=1e-12 * abs(Qd).max())


def test_position_reduction_is_eq_15(cylinder):
    """The tool finds eq (15): [Pd, x, xdot], dPd/dt = (a - b) xdot + (c - d) v."""
    red = observable_reduction(cylinder, ("x3",))
    assert red.z_names == ("Pd", "x", "xdot") and red.rank == 3
    assert red.T == sp.Matrix([[1, -1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    g, A, Pp, Pn, x, L, V0, K, R, Ts, M, Ff = sp.symbols(
        "gamma A Pp Pn x L V0 K R Ts M Ff", real=True)
    Vp, Vn = V0 + A * x, V0 + A * (L - x)
    a, b = -g * A * Pp / Vp, g * A * Pn / Vn
    c, d = K * g * R * Ts / Vp, -K * g * R * Ts / Vn
    expected_A = sp.Matrix([[0, 0, a - b], [0, 0, 1], [A / M, 0, -Ff / M]])
    expected_B = sp.Matrix([c - d, 0, 0])
    assert sp.simplify(red.A_r - expected_A) == sp.zeros(3, 3)
    assert sp.simplify(red.B_r - expected_B) == sp.zeros(3, 1)
    assert red.C_r == sp.Matrix([[0, 1, 0]])
    # the common-mode pressure is the unobservable mode: an integrator at the point
    assert np.allclose(red.unobservable_eigenvalues, 0, atol=1e-9)


def test_pressure_difference_reduction_drops_position(cylinder):
    red = observable_reduction(cylinder, ("pp - pn",))
    assert red.z_names == ("Pd", "xdot") and red.rank == 2
    lin = linearise(cylinder)
    np.testing.assert_allclose(red.T_num @ lin.A, red.A_num @ red.T_num, atol=1e-6)


@pytest.mark.parametrize("rows", [[0], [2], [2, 3], [0, 2, 3], [1]])
def test_rank_matches_python_control(cylinder, rows):
    lin = linearise(cylinder)
    C = lin.C[rows]
    O = control.obsv(lin.A, C)
    scaled = O / np.linalg.norm(O, axis=0).clip(1e-300)
    assert observability_rank(lin.A, C) == np.linalg.matrix_rank(scaled, tol=1e-9)


def test_discrete_gain_matches_scipy_dare(cylinder):
    red = observable_reduction(cylinder, ("x3",))
    from fdigen.derive.linearisation import LinearModel
    lin = LinearModel(red.A_num, red.B_num, red.C_num, np.zeros((1, 1)), np.zeros((3, 0)),
                      np.zeros((1, 0)), np.zeros(3), np.zeros(1), np.zeros(1))
    disc = discretise_zoh(lin, 1e-3)
    Q = np.diag([1e4, 1e-12, 1e-4])
    R = np.array([[4e-10]])
    gain = discrete_kalman_gain(disc.A, disc.C, Q, R)
    P = scipy.linalg.solve_discrete_are(disc.A.T, disc.C.T, Q, R)
    M = P @ disc.C.T @ np.linalg.inv(disc.C @ P @ disc.C.T + R)
    np.testing.assert_allclose(gain.P, P, rtol=1e-6)
    np.testing.assert_allclose(gain.M, M, rtol=1e-6)
    np.testing.assert_allclose(gain.L, disc.A @ M, rtol=1e-6)
    assert np.all(np.abs(gain.poles) < 1)
    cg = continuous_kalman_gain(red.A_num, red.C_num, Q, R * 1e-3)
    Pc = scipy.linalg.solve_continuous_are(red.A_num.T, red.C_num.T, Q, R * 1e-3)
    np.testing.assert_allclose(cg.L, Pc @ red.C_num.T / (R * 1e-3), rtol=1e-5)


def test_non_detectable_pair_is_a_clear_error(cylinder):
    """[Pd, x, xdot] measured by Pd alone: x is an unobservable integrator."""
    red = observable_reduction(cylinder, ("x3",))
    from fdigen.derive.linearisation import LinearModel
    lin = LinearModel(red.A_num, red.B_num, red.C_num, np.zeros((1, 1)), np.zeros((3, 0)),
                      np.zeros((1, 0)), np.zeros(3), np.zeros(1), np.zeros(1))
    disc = discretise_zoh(lin, 1e-3)
    C_pd = np.array([[1.0, 0.0, 0.0]])
    with pytest.raises(DesignError, match="not detectable"):
        discrete_kalman_gain(disc.A, C_pd, np.eye(3), np.eye(1))
    with pytest.raises(DesignError, match="not detectable"):
        continuous_kalman_gain(red.A_num, C_pd, np.eye(3), np.eye(1))


@pytest.mark.parametrize("Q,R,match", [
    (np.eye(3), np.zeros((1, 1)), "positive definite"),
    (-np.eye(3), np.eye(1), "semidefinite"),
    (np.eye(3), np.array([[np.nan]]), "not finite"),
    (np.eye(2), np.eye(1), "must be 3x3"),
])
def test_bad_noise_weights(cylinder, Q, R, match):
    red = observable_reduction(cylinder, ("x3",))
    A = scipy.linalg.expm(red.A_num * 1e-3)
    with pytest.raises(DesignError, match=match):
        discrete_kalman_gain(A, red.C_num, Q, R)


def test_nothing_observable_is_an_error(cylinder):
    with pytest.raises(DesignError, match="nothing is observable"):
        observable_reduction(cylinder, ("0*x3",))


def test_gains_equal_python_control(cylinder_design):
    """derive/kalman.py computes python-control's dlqe/lqe gains without importing
    python-control at build time. Its result is refined to the correctly rounded solution
    (docs/reproducibility.md), control's is accurate to what its unrefined double solve of
    the badly scaled equation gives (~1e-10 relative for R4, whose state mixes pressures in
    Pa and a position in m): equal within 1e-8 of each matrix's largest entry."""
    dt = cylinder_design.config.sample_time

    def close(got, want, what):
        np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-8 * np.abs(want).max(),
                                   err_msg=what)

    for k in cylinder_design.kalman:
        red = k.reduction
        Qd = discretise_noise(red.A_num, k.Qc, dt)
        n = red.A_num.shape[0]
        L, P, E = control.dlqe(k.discrete.A, np.eye(n), k.discrete.C, Qd, k.Rd)
        close(k.gain.L, L, k.residual)
        close(k.gain.P, P, k.residual)
        np.testing.assert_allclose(np.sort_complex(k.gain.poles), np.sort_complex(E),
                                   rtol=1e-9, err_msg=k.residual)
        Lc, Pc, Ec = control.lqe(red.A_num, np.eye(n), red.C_num, k.Qc, k.Rd * dt)
        close(k.continuous_gain.L, Lc, k.residual)


def _dare_residual(A, C, Q, R, P):
    """max |A P A^T - A P C^T (C P C^T + R)^-1 C P A^T + Q - P| in 200-bit arithmetic."""
    import mpmath as mp

    with mp.workprec(200):
        A, C, Q, R, P = (mp.matrix(np.asarray(M, dtype=float).tolist()) for M in (A, C, Q, R, P))
        APC = A * P * C.T
        F = A * P * A.T - APC * mp.inverse(C * P * C.T + R) * APC.T + Q - P
        return float(max(abs(F[i, j]) for i in range(F.rows) for j in range(F.cols)))


def test_refined_riccati_solution_is_independent_of_its_start(cylinder_design):
    """The Newton refinement converges to the same doubles from python-control's solution,
    from a start perturbed by 1e-6 and from its own result (a fixed point), and that
    solution satisfies the Riccati equation better than control's."""
    from fdigen.derive import riccati

    dt = cylinder_design.config.sample_time
    for k in cylinder_design.kalman:
        red = k.reduction
        A, C, R = k.discrete.A, k.discrete.C, k.Rd
        Q = discretise_noise(red.A_num, k.Qc, dt)
        _, P_control, _ = control.dlqe(A, np.eye(A.shape[0]), C, Q, R)
        for start in (P_control, P_control * (1 + 1e-6), k.gain.P):
            sol = riccati.refine(A, C, Q, R, start, discrete=True)
            np.testing.assert_array_equal(sol["P"], k.gain.P, err_msg=k.residual)
            np.testing.assert_array_equal(sol["M"], k.gain.M, err_msg=k.residual)
        assert _dare_residual(A, C, Q, R, k.gain.P) <= _dare_residual(A, C, Q, R, P_control)


@pytest.mark.parametrize("discrete", [True, False])
def test_refinement_keeps_structural_zeros_exact(discrete):
    """Two decoupled states: the cross covariance is zero in exact arithmetic. Whatever the
    start (here off-diagonal noise of either sign, as different BLAS kernels leave it),
    the refined P, gains and poles are the same bits, with exact zeros off the diagonal."""
    from fdigen.derive import riccati

    A = np.array([[0.95, 0.0], [0.0, 0.8]]) if discrete else np.array([[-1.5, 0.0],
                                                                      [0.0, -40.0]])
    C, Q, R = np.eye(2), np.diag([1e4, 1e-6]), np.diag([4e-10, 2.5e-3])
    P0 = riccati.double_start(A, C, Q, R, None, discrete)
    results = [riccati.refine(A, C, Q, R, P0 + noise * np.array([[0, 1], [1, 0]]), discrete)
               for noise in (0.0, 1e-13, -3e-12)]
    for sol in results[1:]:
        for key in ("P", "M", "L", "S", "poles"):
            np.testing.assert_array_equal(sol[key], results[0][key], err_msg=key)
    P = results[0]["P"]
    assert P[0, 1] == 0.0 and P[1, 0] == 0.0 and np.all(np.diag(P) > 0)
    gain = (discrete_kalman_gain if discrete else continuous_kalman_gain)(A, C, Q, R)
    np.testing.assert_array_equal(gain.P, P)


@pytest.mark.parametrize("make", [
    lambda g: sp.sign(g) * sp.sqrt(sp.Abs(g)), lambda g: sp.Abs(g) ** 3,
    lambda g: sp.Max(g, 0) + sp.Min(g, 1), lambda g: g * sp.Heaviside(g),
    lambda g: sp.Abs(sp.sign(g) * g)])
def test_nonsmooth_derivative_of_an_argument_sympy_cannot_prove_real(make):
    """``h - (y + d)/k`` (a scaled sensor's inverse with a fault ``d``): sympy cannot prove it
    real (``k`` may be 0) and leaves ``Derivative(sign(...), d)``, which then fails at
    ``d = 0``. The almost-everywhere Jacobian is evaluated instead and equals central
    differences at seeded points away from the kinks."""
    from fdigen.derive.nonsmooth import jacobian

    h, y, k, d = sp.symbols("h y k d", real=True)
    expr = make(h - (y + d) / k)
    J = jacobian([expr], [h, d]).xreplace({d: 0})
    assert not J.has(sp.Derivative) and not J.has(sp.DiracDelta)
    fn = sp.lambdify((h, y, k, d), expr, "math")
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(40):
        hv, yv, kv = rng.uniform(-3, 3), rng.uniform(-1, 1), rng.uniform(0.1, 2)
        g0 = hv - yv / kv
        if min(abs(g0), abs(g0 - 1)) < 1e-3:
            continue
        got = [float(v) for v in J.xreplace({h: hv, y: yv, k: kv})]
        e = 1e-6 * min(1.0, abs(g0), abs(g0 - 1))
        want = [(fn(hv + e, yv, kv, 0) - fn(hv - e, yv, kv, 0)) / (2 * e),
                (fn(hv, yv, kv, e) - fn(hv, yv, kv, -e)) / (2 * e)]
        assert np.allclose(got, want, rtol=1e-5, atol=1e-7), (hv, yv, kv, got, want)
        checked += 1
    assert checked >= 30
