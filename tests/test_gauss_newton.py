"""The Gauss-Newton Hessian of the output-error fits (fdigen.discover.gauss_newton)."""

from __future__ import annotations

import casadi as ca
import numpy as np

from fdigen.discover.gauss_newton import gauss_newton_hessian


def _residual(w):
    return ca.vertcat(10 * (w[1] - w[0] ** 2), 1 - w[0], 0.5 * ca.sin(w[0] * w[1]))


def test_hessian_is_lam_f_times_jacobian_product():
    """triu(lam_f J^T J), J by central differences at seeded points."""
    w = ca.MX.sym("w", 2)
    hess = gauss_newton_hessian(_residual(w), w, 1)
    r = ca.Function("r", [w], [_residual(w)])
    rng = np.random.default_rng(3)
    for _ in range(5):
        x, lam = rng.normal(size=2), float(rng.uniform(0.5, 2.0))
        jac = np.column_stack([(np.asarray(r(x + e)) - np.asarray(r(x - e))).ravel() / 2e-6
                               for e in np.eye(2) * 1e-6])
        got = np.asarray(ca.densify(hess(x, ca.DM(0, 1), lam, 0.0)))
        np.testing.assert_allclose(got, np.triu(lam * jac.T @ jac), rtol=1e-6, atol=1e-6)


def test_ipopt_with_it_reaches_the_exact_hessians_minimum():
    """A constrained least-squares problem (Rosenbrock's valley and a circle): IPOPT with
    the Gauss-Newton Hessian ends where IPOPT with the exact one does."""
    w = ca.MX.sym("w", 2)
    res = _residual(w)
    g = w[0] ** 2 + w[1] ** 2 - 1.5
    nlp = {"x": w, "f": 0.5 * ca.sumsqr(res), "g": g}
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"}
    exact = ca.nlpsol("e", "ipopt", nlp, opts)
    gn = ca.nlpsol("g", "ipopt", nlp, {**opts, "hess_lag": gauss_newton_hessian(res, w, 1)})
    a = exact(x0=[-1.2, 1.0], lbg=-np.inf, ubg=0)
    b = gn(x0=[-1.2, 1.0], lbg=-np.inf, ubg=0)
    assert gn.stats()["success"] and exact.stats()["success"]
    np.testing.assert_allclose(np.asarray(b["x"]).ravel(), np.asarray(a["x"]).ravel(),
                               atol=1e-6)
    assert float(a["f"]) < 0.5  # a real minimum, not the start (f = 12.1 there)
