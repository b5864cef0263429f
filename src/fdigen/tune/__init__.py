"""Threshold tuning by Monte Carlo: thresholds designed for a false-alarm rate, not guessed.

``fdigen tune`` runs two campaigns of closed-loop simulations (:func:`fdigen.sim.plant.simulate`)
each followed by the compiled C FDI core (:func:`fdigen.detect.fdi_runner`), on Dask:

1. **Healthy campaign** (design thresholds). ``N`` fault-free runs with

   * independent sensor-noise seeds,
   * demand variations: the ``[simulation]`` reference :math:`r(t)` is replaced per run by
     :math:`c + a\\,(r(t + \\tau) - c)` with amplitude scale :math:`a \\sim U(a_0, a_1)`,
     time shift (phase of every sine) :math:`\\tau \\sim U(0, \\tau_1)` and :math:`c` the mean
     demand; the plant starts at the operating point as on the rig, so the start-up step
     :math:`r(\\tau) - x_0` varies too,
   * parameter spread: every parameter with ``uncertain = true`` drawn uniformly within
     :math:`\\pm` ``tolerance`` (datasheet: 10 %) of its value and clipped to its bounds.

   The FDI core runs with every threshold at ``1e30``, so no flag ever rises, the parallel
   model is never frozen, and the RMS trajectory is the one the core follows *until* its
   first flag whatever the thresholds. Hence, exactly, a run false-alarms on residual
   :math:`i` iff :math:`M_i = \\max_k \\mathrm{RMS}_i[k] > J_i`. ``M_i`` is taken after a
   settling time (default: one RMS window, over which the RMS is still a partial sum); the
   start-up maximum :math:`S_i` (before settling) is recorded too and, as the core has no
   start-up gating, no threshold is set below it.

   Per residual, the per-run maxima are fitted by a Gumbel and a generalized extreme value
   (GEV) distribution (maximum likelihood, ``scipy.stats``):

   .. math::

       F_\\mathrm{GEV}(x) = \\exp\\left\\{-\\left[1 + \\xi\\frac{x-\\mu}{\\sigma}\\right]^{-1/\\xi}
       \\right\\},\\qquad F_\\mathrm{Gumbel}(x) = \\exp\\{-e^{-(x-\\mu)/\\sigma}\\}\\ (\\xi = 0)

   The GEV is used when a likelihood-ratio test rejects the Gumbel,
   :math:`2(\\ell_\\mathrm{GEV} - \\ell_\\mathrm{Gumbel}) > \\chi^2_{1;0.95} = 3.84`. The target
   false-alarm probability per run :math:`\\alpha` is shared among the :math:`n_r`
   residuals (Sidak), :math:`\\alpha_i = 1 - (1 - \\alpha)^{1/n_r}`, and

   .. math::

       q_i = F^{-1}(1 - \\alpha_i) = \\mu + \\frac{\\sigma}{\\xi}
       \\left[(-\\ln(1 - \\alpha_i))^{-\\xi} - 1\\right]
       \\quad\\left(\\xi \\to 0:\\ \\mu - \\sigma\\ln(-\\ln(1 - \\alpha_i))\\right),

   .. math::

       J_i = m \\cdot \\max(q_i, \\max_\\mathrm{runs} M_i, \\max_\\mathrm{runs} S_i)

   with the safety margin :math:`m` (default 1.25), rounded *up* to three significant
   digits. With fewer than ``min_fit_runs`` runs no fit is trusted: :math:`J_i = m
   \\max(M_i, S_i)` over the runs and the estimate is reported as *empirical*. The
   fitted run-level false-alarm probability is :math:`1 - \\prod_i F_i(J_i)`; the
   empirical one is checked on fresh validation runs with the tuned core (flags, freeze
   and isolation live), with a one-sided 95 % Clopper-Pearson upper bound.

2. **Fault campaign** (tuned thresholds). The design is rebuilt with the tuned thresholds
   (``dataclasses.replace(model, fdi=...)`` then :func:`~fdigen.design.cache.cached_design`:
   freeze, realignment and isolation depend on the flags). Each fault of the model at
   ``factor * test_size`` for each factor (additive sensor faults as ramps of
   ``factor * test_size`` per second; multiplicative faults with a test size of at most 1
   in magnitude clipped to magnitude 1: a loss of at most 100 %), at
   several start times, with parameter spread and demand variation as above. Per run: the
   detection delay (first new flag after onset), the isolation delay and whether the
   isolated class is the fault's class; per fault, missed detections and false isolations.

Every task is one simulation plus one FDI run and returns a small summary (maxima, times),
never the log. Cost (``bench/tune_throughput.py``; the C FDI core adds < 1 % to the
simulation, RK4 with 10 sub-steps in the CasADi virtual machine): about 1.2e4 simulated
samples/s per core on an idle machine, with a 1.6-1.9x speed-up from 1 to 2 Dask workers;
on this shared 2-core machine under a load average of 3-6 from other processes, 1.5e3-3.7e3
samples/s per task. The default campaign (40 healthy runs of 10 s, 10 validation runs,
9 faults x 4 sizes x 2 onsets: 1.16e6 samples) took 4.5-8.7 minutes measured there
(about 2 minutes extrapolated for 2 idle cores, start-up and one design derivation
included). A full campaign, ``--runs 500 --duration 20`` (1.15e7 samples), takes about
10-15 minutes on 2 idle cores and 45-90 minutes on a loaded machine.

The package, one concept per module:

* :mod:`~fdigen.tune.settings` -- :class:`TuneSettings`, :class:`Case`, :data:`NO_FLAG`;
* :mod:`~fdigen.tune.cases` -- parameter spread, varied demand, :func:`make_cases`;
* :mod:`~fdigen.tune.runs` -- one task: :func:`run_case`, :func:`summarise_case`;
* :mod:`~fdigen.tune.campaign` -- :class:`CampaignExecutor` (Dask or in-process);
* :mod:`~fdigen.tune.extremes` -- GEV / Gumbel fit, :func:`clopper_pearson_upper`;
* :mod:`~fdigen.tune.thresholds` -- :func:`design_thresholds`, :func:`round_up`;
* :mod:`~fdigen.tune.fault_summary` -- :func:`summarise_faults`;
* :mod:`~fdigen.tune.model_update` -- writing thresholds into the model file,
  :func:`design_with_thresholds`;
* :mod:`~fdigen.tune.pipeline` -- :func:`tune`, the whole procedure.
"""

from __future__ import annotations

from fdigen.tune.campaign import CampaignExecutor
from fdigen.tune.cases import demand_expression, make_cases, perturbed_parameters
from fdigen.tune.extremes import (LR_CRITICAL, clopper_pearson_upper, coles_dixon_penalty,
                                  fit_maxima, gev_cdf, gev_quantile)
from fdigen.tune.fault_summary import summarise_faults
from fdigen.tune.model_update import (design_with_thresholds, thresholds_snippet,
                                      updated_model_text, write_thresholds)
from fdigen.tune.pipeline import tune
from fdigen.tune.runs import run_case, summarise_case
from fdigen.tune.settings import NO_FLAG, Case, TuneSettings
from fdigen.tune.thresholds import design_thresholds, round_up

__all__ = [
    "CampaignExecutor", "Case", "LR_CRITICAL", "NO_FLAG", "TuneSettings",
    "clopper_pearson_upper", "coles_dixon_penalty", "demand_expression",
    "design_thresholds", "design_with_thresholds", "fit_maxima", "gev_cdf", "gev_quantile",
    "make_cases", "perturbed_parameters", "round_up", "run_case", "summarise_case",
    "summarise_faults", "thresholds_snippet", "tune", "updated_model_text",
    "write_thresholds",
]
