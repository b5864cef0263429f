"""A first-order low-pass on the innovation of a derived Kalman filter.

A Kalman filter's innovation is white on a healthy plant, with the variance
:math:`S = C P C^T + R`; a fault the filter only partly absorbs (a sensor offset on a
driving measurement, a slow drift) leaves a small bias :math:`b` in it. The moving RMS
over :math:`N` samples reads :math:`\\sqrt{S + b^2}`: it never averages the noise away, so
a bias below about :math:`\\sqrt{S}` barely moves it, however long it lasts. Filtering the
innovation before the RMS,

.. math:: w_k = \\alpha\\, w_{k-1} + (1 - \\alpha)\\, e_k, \\qquad
          \\alpha = e^{-T_s/\\tau},

keeps the bias (unit DC gain) and divides the noise's standard deviation by
:math:`\\sqrt{(1+\\alpha)/(1-\\alpha)}` (about :math:`\\sqrt{2\\tau/T_s}`): the residual's RMS is
then mostly :math:`|b|`, and a threshold set by noise and calibrated parameters sits near
the bias the design must see. The filter adds a lag of about :math:`\\tau` to a fault's
first flag. The filter's state starts at 0 and is one more entry of the FDI state
(``<R>_lp``); the Kalman update still uses the raw innovation.

``[fdi] innovation_filter`` sets :math:`\\tau` in seconds for the design's *derived* Kalman
residuals (declared ones are what the model file says they are); 0 switches it off. The
residual's key (:mod:`fdigen.design.residual_identity`) names the filter, so a threshold
written for the unfiltered residual is never applied to the filtered one.
"""

from __future__ import annotations

import math


def innovation_alpha(tau: float, sample_time: float) -> float:
    """The filter's pole :math:`\\alpha = e^{-T_s/\\tau}` (0 for ``tau = 0``: no filter)."""
    return math.exp(-sample_time / tau) if tau > 0 else 0.0


def noise_factor(alpha: float) -> float:
    """Standard deviation of the filtered white innovation over the raw one:
    :math:`\\sqrt{(1-\\alpha)/(1+\\alpha)}`."""
    return math.sqrt((1.0 - alpha) / (1.0 + alpha))


def filtered_realisation(tau: float) -> str:
    """The realisation named in a filtered derived Kalman residual's key."""
    return f"Kalman filter, innovation low-passed over {tau:g} s"


def filtered_kalman(cfg, residual: str) -> bool:
    """Whether ``residual`` is a derived Kalman residual whose innovation is filtered."""
    return cfg.innovation_filter > 0 and residual not in {k.residual for k in cfg.kalman}
