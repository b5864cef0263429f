"""A fitted model's free-run error on another log: its initial state estimated on the
log's beginning, then one free run over the whole log.

The error a fit makes on a second log (``discover --validate``, the output-error loop's
confirmation) is a free run with the parameters fixed from an initial state the second
log's data decide. That state was a multiple-shooting fit over the whole log: on a user's
hydraulic axis (16,000 samples at 1 ms, stiff pressure dynamics) one such fit ran past
ten minutes, and ``commission --validate`` never got past discover. The state is now
fitted on the first :data:`PREFIX` samples only (multiple shooting, the parameters held),
and the whole log is run once from it (:func:`fdigen.discover.output_error.simulate`):

.. math:: \\hat x_0 = \\arg\\min_{x_0} \\sum_{k < K_0} \\| W (y_k - \\hat y_k(x_0, \\theta)) \\|^2,
          \\qquad \\mathrm{RMS}_j = \\sqrt{\\tfrac{1}{K} \\sum_{k < K}
          (y_{kj} - \\hat y_{kj}(\\hat x_0, \\theta))^2}

with :math:`K_0 = \\min(K, 1000)`.
"""

from __future__ import annotations

import numpy as np

#: Samples at the beginning of a log its initial state is fitted on.
PREFIX = 1000


def free_run_rms(model, t, u, y, *, effects=(), params: dict, bounds: dict,
                 sigma=None) -> np.ndarray:
    """Free-run RMS per output of ``model`` (with ``effects``, at ``params``) over the log
    ``(t, u, y)``, from an initial state fitted on its first :data:`PREFIX` samples."""
    from fdigen.discover.output_error import (accurate_substeps, build_model,
                                              fit_output_error, simulate)

    t, u, y = np.asarray(t, float), np.asarray(u, float), np.asarray(y, float)
    k0 = min(len(t), PREFIX)
    fit = fit_output_error(model, t[:k0], u[:k0], y[:k0], [], bounds, effects=effects,
                           start=params, hold={}, report=False, sigma=sigma)
    if k0 == len(t):
        return np.asarray(fit.rms, float)
    dt = float(np.median(np.diff(t)))
    om = build_model(model, effects, dt, accurate_substeps(model, dt))
    _, Y = simulate(om, fit.x0, u, {**params, **fit.params})
    return np.sqrt(np.nanmean((y - Y) ** 2, axis=0))
