"""The Gauss-Newton Hessian of a least-squares NLP, for CasADi's IPOPT interface.

The output-error fits (:mod:`fdigen.discover.output_error`) minimise half the sum of
squared, noise-weighted output errors of a multiple-shooting simulation. IPOPT's exact
Hessian of that Lagrangian needs second derivatives through every simulated step; the
Gauss-Newton Hessian needs only the Jacobian of the errors.
"""

from __future__ import annotations

import casadi as ca

#: Iterations of the Gauss-Newton fit before the exact Hessian takes over
#: (:func:`gauss_newton_hessian`): a fit that converges does so in 5-15 on the logs of the
#: test suite and the users' plants; one that stalls never would.
GAUSS_NEWTON_ITERATIONS = 30


def gauss_newton_hessian(residual, w, n_constraints: int):
    r"""The Gauss-Newton Hessian of the Lagrangian of a least-squares NLP, as the
    ``hess_lag`` function CasADi's IPOPT interface takes.

    .. math:: \nabla^2_{ww} L \approx \lambda_f\, J^T J, \quad J = \partial r / \partial w

    for the cost :math:`\tfrac12 \lVert r(w) \rVert^2`; the constraints' curvature (the
    shooting nodes' continuity, weighted by their multipliers) is left out. On the
    output-error fits the exact Hessian, second derivatives through every step of every
    segment's simulation, took three quarters of the solver's time (a 6000-sample log:
    10.5 of 14 s); this one needs first derivatives only (2.5 s), and the fit converges
    to the same parameters in a few more iterations where it converges.
    """
    lam_f = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", n_constraints)
    jac = ca.jacobian(residual, w)
    hess = ca.triu(lam_f * ca.mtimes(jac.T, jac))
    return ca.Function("nlp_hess_l", [w, ca.MX.sym("p", 0), lam_f, lam_g], [hess],
                       ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
