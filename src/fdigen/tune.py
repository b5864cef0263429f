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
   ``factor * test_size`` per second; multiplicative faults clipped to magnitude 1), at
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
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import time
import warnings
from decimal import Decimal
from pathlib import Path

import numpy as np

from fdigen.errors import FdigenError

#: Threshold used to switch flags off in the healthy campaign (finite: the config needs it).
NO_FLAG = 1e30
#: chi^2 with one degree of freedom, 95 %: the likelihood-ratio test GEV vs Gumbel.
LR_CRITICAL = 3.841458820694124


@dataclasses.dataclass(frozen=True)
class TuneSettings:
    """Campaign settings.

    Attributes
    ----------
    runs : int
        Healthy runs used to tune the thresholds.
    duration : float
        Seconds per run (the false-alarm rate is per run of this length).
    false_alarm_rate : float
        Target probability :math:`\\alpha` that a healthy run raises any flag.
    margin : float
        Safety factor :math:`m \\ge 1` on the quantile.
    tolerance : float
        Relative spread of the ``uncertain`` parameters (uniform, +-).
    settle : float or None
        Seconds excluded from the maxima (default: one RMS window).
    ref_scale : tuple of float
        Range of the demand amplitude scale :math:`a`.
    ref_shift : float
        Upper end of the demand time shift :math:`\\tau` [s].
    validation_runs : int
        Fresh healthy runs checked with the tuned core.
    fault_factors : tuple of float
        Fault sizes relative to each fault's ``test_size``.
    fault_starts : int
        Onset times per fault and size, evenly spaced in [0.35, 0.65] of the duration.
    faults : tuple of str or None
        Faults of the campaign (default: all the model's faults).
    min_fit_runs : int
        Below this many runs, thresholds are empirical (no extreme-value fit).
    seed : int
        Master seed: every run's noise seed, parameters and demand derive from it.
    keep : tuple of str
        Residuals whose thresholds stay as in the model file (a design decision rather
        than a noise statistic, e.g. the voter's); still fitted and reported.
    """

    runs: int = 40
    duration: float = 10.0
    false_alarm_rate: float = 0.01
    margin: float = 1.25
    tolerance: float = 0.10
    settle: float | None = None
    ref_scale: tuple = (0.8, 1.1)
    ref_shift: float = 100.0
    validation_runs: int = 10
    fault_factors: tuple = (0.25, 0.5, 1.0, 2.0)
    fault_starts: int = 2
    faults: tuple | None = None
    min_fit_runs: int = 20
    seed: int = 0
    keep: tuple = ()

    def __post_init__(self):
        if self.runs < 2:
            raise FdigenError("tune needs at least 2 healthy runs")
        if not 0 < self.false_alarm_rate < 1:
            raise FdigenError("the false-alarm rate must be in (0, 1)")
        if self.margin < 1:
            raise FdigenError("the safety margin must be >= 1")
        if self.duration <= 0:
            raise FdigenError("the duration must be positive")


@dataclasses.dataclass(frozen=True)
class Case:
    """One task: a closed-loop run and its FDI evaluation (small, picklable)."""

    kind: str                      # "healthy", "validation" or "fault"
    index: int
    seed: int
    duration: float
    parameters: dict
    ref_scale: float
    ref_shift: float
    fault: tuple | None = None     # (name, t0, size, ramp)
    factor: float | None = None
    plant: object = None           # Model simulated (None: the design's own model)
    effects: tuple = ()            # fdigen.sim.plant.Effect switched on in the plant


# -- run generation ----------------------------------------------------------------------
def perturbed_parameters(model, rng, tolerance: float) -> dict:
    """Uncertain parameters drawn uniformly in :math:`p_0 (1 \\pm \\mathrm{tol})`, clipped
    to their bounds."""
    out = {}
    for q in model.parameters:
        if q.uncertain:
            v = q.value * (1.0 + rng.uniform(-tolerance, tolerance))
            if q.bounds is not None:
                v = min(max(v, q.bounds[0]), q.bounds[1])
            out[q.name] = float(v)
    return out


def _reference_centre(model) -> float:
    from fdigen.sim.plant import reference_signal

    return float(np.mean(reference_signal(model, np.arange(0.0, 200.0, 0.01))))


def demand_expression(model, scale: float, shift: float, centre: float | None = None,
                      blend: float = 1.0) -> str:
    """The varied demand as an expression of ``t``.

    .. math::

        r'(t) = c + a\\left[r(t + \\tau) - c + (r(0) - r(\\tau))\\,e^{-t/T_b}\\right]

    The multi-sine is shifted by :math:`\\tau` (every sine's phase changes) and scaled by
    :math:`a` about its mean :math:`c`, but the run *starts* like the rig's: the initial
    demand is the nominal one scaled by :math:`a`, blended into the shifted demand with
    time constant :math:`T_b` (``blend`` s), so the start-up step from the operating point
    is the rig's step times :math:`a`, not a random one.
    """
    from fdigen.sim.plant import reference_signal

    ref = model.simulation["reference"]
    c = _reference_centre(model) if centre is None else centre
    r0, rtau = reference_signal(model, np.array([0.0, float(shift)]))
    shifted = re.sub(r"\bt\b", f"(t + {float(shift)!r})", ref)
    offset = float(r0 - rtau)
    return (f"{c!r} + {float(scale)!r}*(({shifted}) - {c!r} + {offset!r}*exp(-t/{blend!r}))")


def _fault_sizes(fault, factors):
    sizes = []
    for k in factors:
        s = float(k) * fault.test_size
        if fault.mode == "multiplicative":
            s = float(np.clip(s, -1.0, 1.0))
        if all(abs(s - t) > 1e-12 * max(1.0, abs(s)) for t, _ in sizes):
            sizes.append((s, float(k)))
    return sizes


def make_cases(model, settings: TuneSettings, plant=None,
               effects=()) -> dict[str, list[Case]]:
    """Every run of the campaigns, drawn from the master seed (reproducible).

    With ``plant`` (a Model) the runs simulate that model instead of the design's, with
    the extra ``effects`` (:class:`fdigen.sim.plant.Effect`) switched on; the parameter
    spread is drawn around the plant's values. Two designs tuned with the same plant,
    effects and seed see exactly the same runs.
    """
    sim_model = model if plant is None else plant
    effects = tuple(effects)
    ss = np.random.SeedSequence(settings.seed)
    streams = dict(zip(("healthy", "validation", "fault"), ss.spawn(3)))
    lo, hi = settings.ref_scale

    def draw(kind, n):
        rngs = [np.random.default_rng(s) for s in streams[kind].spawn(n)]
        return [(int(r.integers(2**31 - 1)), perturbed_parameters(sim_model, r,
                                                                 settings.tolerance),
                 float(r.uniform(lo, hi)), float(r.uniform(0.0, settings.ref_shift)))
                for r in rngs]

    out = {}
    for kind, n in (("healthy", settings.runs), ("validation", settings.validation_runs)):
        out[kind] = [Case(kind, i, seed, settings.duration, pars, a, tau, plant=plant,
                          effects=effects)
                     for i, (seed, pars, a, tau) in enumerate(draw(kind, n))]
    names = (tuple(f.name for f in model.faults) if settings.faults is None
             else tuple(settings.faults))
    known = {f.name for f in model.faults}
    for name in names:
        if name not in known:
            raise FdigenError(f"unknown fault '{name}' (model faults: {', '.join(sorted(known))})")
    starts = (np.linspace(0.35, 0.65, settings.fault_starts) if settings.fault_starts > 1
              else np.array([0.5])) * settings.duration
    specs = []
    for name in names:
        f = model.fault(name)
        ramp = f.location == "sensor" and f.mode == "additive"
        for size, k in _fault_sizes(f, settings.fault_factors):
            for t0 in starts:
                specs.append(((name, float(round(t0, 3)), size, ramp), k))
    out["fault"] = [Case("fault", i, seed, settings.duration, pars, a, tau, spec, k,
                         plant=plant, effects=effects)
                    for i, ((spec, k), (seed, pars, a, tau))
                    in enumerate(zip(specs, draw("fault", len(specs))))]
    return out


# -- one task ----------------------------------------------------------------------------
_RUNNERS: dict = {}      # id(design) -> (design, runner): the scattered object, per task
_BY_CONTENT: dict = {}   # model hash (thresholds included) -> runner
_CENTRES: dict = {}


def _runner(design):
    """The C core of ``design``, built once per process (and per distinct design)."""
    hit = _RUNNERS.get(id(design))
    if hit is not None and hit[0] is design:
        return hit[1]
    from fdigen.detect import fdi_runner
    from fdigen.model.model_file import model_hash

    key = model_hash(design.model)
    runner = _BY_CONTENT.get(key)
    if runner is None:
        if len(_BY_CONTENT) > 4:
            _BY_CONTENT.clear()
            _RUNNERS.clear()
        runner = _BY_CONTENT[key] = fdi_runner(design, "c")
    _RUNNERS[id(design)] = (design, runner)
    return runner


def run_case(design, case: Case, settle_samples: int) -> dict:
    """Simulate one closed-loop run and evaluate it with the C core of ``design``.

    Returns a small summary: per-residual maxima of the RMS (residual -> value, after
    ``settle_samples`` and before), first flag, isolated class, and for a fault run its
    onset and delays. Errors
    are returned (``{"error": ...}``), not raised, so one bad run names itself.
    """
    try:
        from fdigen.sim.plant import FaultEvent, simulate

        model = design.model if case.plant is None else case.plant
        key = (model.name, model.simulation.get("reference"))
        if key not in _CENTRES:
            _CENTRES[key] = _reference_centre(model)
        sim_model = dataclasses.replace(model, simulation={
            **model.simulation,
            "reference": demand_expression(model, case.ref_scale, case.ref_shift,
                                           _CENTRES[key])})
        faults = () if case.fault is None else (FaultEvent(*case.fault),)
        runner = _runner(design)
        t0, c0 = time.perf_counter(), time.process_time()
        sim = simulate(sim_model, case.duration, faults=faults, parameters=case.parameters,
                       seed=case.seed, effects=case.effects)
        t1, c1 = time.perf_counter(), time.process_time()
        out = runner.run(sim.u, sim.y)
        t2, c2 = time.perf_counter(), time.process_time()
        return summarise_case(design, case, sim.t, out, settle_samples,
                              timing={"simulate": t1 - t0, "fdi": t2 - t1,
                                      "simulate_cpu": c1 - c0, "fdi_cpu": c2 - c1})
    except Exception as exc:  # reported by the driver, with the case
        return {"kind": case.kind, "index": case.index,
                "error": f"{type(exc).__name__}: {exc}"}


def summarise_case(design, case: Case, t, out: dict, settle_samples: int,
                   timing: dict | None = None) -> dict:
    """The small summary of one run (see :func:`run_case`)."""
    ev = design.evaluation
    rms = np.asarray(out["rms"])
    flags = np.asarray(out["flags"], dtype=np.int64)
    cls = np.asarray(out["fault_class"], dtype=np.int64)
    K = len(t)
    s = min(max(int(settle_samples), 0), K - 1)
    res = {"kind": case.kind, "index": case.index, "seed": case.seed,
           "parameters": case.parameters, "ref_scale": case.ref_scale,
           "ref_shift": case.ref_shift, "samples": int(K),
           "max_rms": dict(zip(ev.residuals, rms[s:].max(axis=0).tolist())),
           "t_max": dict(zip(ev.residuals, (float(t[s + k])
                                            for k in rms[s:].argmax(axis=0)))),
           "max_rms_startup": dict(zip(ev.residuals, (rms[:s].max(axis=0) if s else
                                                      np.zeros(rms.shape[1])).tolist())),
           "timing": timing or {}}
    on = np.flatnonzero(flags)
    res["t_first_flag"] = float(t[on[0]]) if on.size else None
    res["flags_raised"] = [ev.residuals[i] for i in range(len(ev.residuals))
                           if flags[-1] >> i & 1]
    res["t_raised"] = {name: float(t[np.flatnonzero(flags >> i & 1)[0]])
                       for i, name in enumerate(ev.residuals) if flags[-1] >> i & 1}
    iso = np.flatnonzero(cls > 0)
    res["isolated"] = ev.classes[int(cls[iso[0]])] if iso.size else "none"
    res["t_isolated"] = float(t[iso[0]]) if iso.size else None
    if case.fault is not None:
        name, onset, size, ramp = case.fault
        k0 = int(np.searchsorted(t, onset - 1e-12))
        fault_class = design.model.fault(name).fault_class
        before = int(flags[k0 - 1]) if k0 > 0 else 0
        new = np.flatnonzero((flags[k0:] & ~before) != 0)
        det = float(t[k0 + new[0]]) if new.size else None
        iso_before = iso.size and iso[0] < k0
        res.update({
            "fault": name, "fault_class": fault_class, "t0": onset, "size": size,
            "ramp": bool(ramp), "factor": case.factor,
            "false_alarm_before_onset": bool(before),
            "detected": det is not None,
            "detection_delay": None if det is None else det - onset,
            "first_residuals": sorted({ev.residuals[i] for i in range(len(ev.residuals))
                                       if new.size and flags[k0 + new[0]] >> i & 1}
                                      - {ev.residuals[i] for i in range(len(ev.residuals))
                                         if before >> i & 1}),
            "isolation_delay": (None if not iso.size or iso_before
                                else float(t[iso[0]]) - onset),
            "isolation_correct": bool(iso.size and not iso_before
                                      and res["isolated"] == fault_class),
        })
        # residuals the structural signature says are blind to this fault, yet raised:
        # before the isolation is confirmed they make the flag pattern match no class
        sig = design.signature_table[name]
        off = sorted(set(res["flags_raised"]) - set(sig))
        t_iso = res["t_isolated"]
        res["off_signature"] = off
        res["off_signature_before_isolation"] = [
            r for r in off if t_iso is None or res["t_raised"][r] <= t_iso]
    return res


# -- executing campaigns -----------------------------------------------------------------
class CampaignExecutor:
    """Runs cases on Dask (a :class:`distributed.LocalCluster` or an existing scheduler)
    or in-process (``scheduler="synchronous"``), with a rich progress bar.

    Parameters
    ----------
    workers : int
        Worker processes of the local cluster (one thread each).
    scheduler : str, optional
        ``None``: start a local cluster; ``"synchronous"``: run in this process; otherwise
        the address of a running Dask scheduler (``tcp://host:8786``), whose workers need
        fdigen (same version) and a C compiler.
    progress : bool
        Show a progress bar (on stderr).
    """

    def __init__(self, workers: int = 2, scheduler: str | None = None, progress: bool = True):
        self.workers = int(workers)
        self.scheduler = scheduler
        self.progress = progress
        self.client = None
        self.cluster = None

    def __enter__(self):
        if self.scheduler == "synchronous":
            return self
        import logging

        from distributed import Client, LocalCluster

        if self.scheduler:
            self.client = Client(self.scheduler)
        else:
            self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1,
                                        processes=True, dashboard_address=None,
                                        silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
        return self

    def __exit__(self, *exc):
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        self.client = self.cluster = None

    @property
    def description(self) -> str:
        if self.client is None:
            return "synchronous (in-process)"
        if self.cluster is not None:
            return f"LocalCluster, {self.workers} worker processes x 1 thread"
        return f"scheduler {self.scheduler}"

    def warm_up(self, design):
        """Import fdigen and compile ``design``'s core on every worker (not timed)."""
        if self.client is None:
            _runner(design)
            return
        self.client.run(_warm, design)

    def run(self, design, cases, settle_samples: int, label: str = "runs") -> list[dict]:
        """Run ``cases`` against ``design``; results in case order."""
        if not cases:
            return []
        from rich.console import Console
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                   TimeElapsedColumn, TimeRemainingColumn)

        bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                       TimeElapsedColumn(), TimeRemainingColumn(),
                       console=Console(stderr=True), disable=not self.progress,
                       transient=False)
        results = []
        with bar:
            task = bar.add_task(label, total=len(cases))
            if self.client is None:
                for case in cases:
                    results.append(run_case(design, case, settle_samples))
                    bar.advance(task)
            else:
                from distributed import as_completed

                dfut = self.client.scatter(design, broadcast=True, hash=False)
                futures = [self.client.submit(run_case, dfut, c, settle_samples, pure=False)
                           for c in cases]
                for fut in as_completed(futures):
                    results.append(fut.result())
                    fut.release()
                    bar.advance(task)
        errors = [r for r in results if "error" in r]
        if errors:
            e = errors[0]
            raise FdigenError(f"{len(errors)} of {len(cases)} {label} failed; first: "
                              f"{e['kind']} run {e['index']}: {e['error']}")
        results.sort(key=lambda r: r["index"])
        return results


def _warm(design, dask_worker=None):
    _runner(design)
    return True


# -- extreme-value statistics ------------------------------------------------------------
def gev_quantile(p: float, xi: float, mu: float, sigma: float) -> float:
    """Quantile of the GEV distribution (Gumbel for :math:`\\xi = 0`).

    .. math::

        F^{-1}(p) = \\mu + \\frac{\\sigma}{\\xi}\\left[(-\\ln p)^{-\\xi} - 1\\right],\\qquad
        \\lim_{\\xi \\to 0} F^{-1}(p) = \\mu - \\sigma \\ln(-\\ln p)
    """
    y = -math.log(p)
    if abs(xi) < 1e-9:
        return mu - sigma * math.log(y)
    return mu + sigma / xi * (y ** (-xi) - 1.0)


def gev_cdf(x: float, xi: float, mu: float, sigma: float) -> float:
    """:math:`F(x) = \\exp\\{-[1 + \\xi (x - \\mu)/\\sigma]^{-1/\\xi}\\}` (Gumbel for
    :math:`\\xi = 0`)."""
    z = (x - mu) / sigma
    if abs(xi) < 1e-9:
        return math.exp(-math.exp(-z))
    arg = 1.0 + xi * z
    if arg <= 0:
        return 0.0 if xi > 0 else 1.0
    return math.exp(-arg ** (-1.0 / xi))


def coles_dixon_penalty(xi: float) -> float:
    """Log of the Coles-Dixon (1999) penalty on the GEV shape for small samples.

    .. math::

        P(\\xi) = \\begin{cases} 1 & \\xi \\le 0 \\\\
        \\exp\\{-\\lambda (1/(1-\\xi) - 1)^{a}\\} & 0 < \\xi < 1 \\\\
        0 & \\xi \\ge 1 \\end{cases}\\qquad \\lambda = a = 1

    It keeps the maximum-likelihood shape finite (:math:`\\xi < 1`, finite mean) and shrinks
    heavy tails that a few runs cannot support.
    """
    if xi <= 0:
        return 0.0
    if xi >= 1:
        return -math.inf
    return -(1.0 / (1.0 - xi) - 1.0)


def _gev_loglik(z, xi, mu, sigma):
    if sigma <= 0:
        return -math.inf
    s = (z - mu) / sigma
    if abs(xi) < 1e-9:
        return float(np.sum(-np.log(sigma) - s - np.exp(-s)))
    arg = 1.0 + xi * s
    if np.any(arg <= 0):
        return -math.inf
    return float(np.sum(-np.log(sigma) - (1.0 + 1.0 / xi) * np.log(arg) - arg ** (-1.0 / xi)))


def fit_maxima(x, alpha: float, min_fit_runs: int = 20) -> dict:
    """Fit Gumbel and GEV to per-run maxima; the :math:`1 - \\alpha` quantile.

    Parameters
    ----------
    x : array_like
        Per-run maxima of one residual's RMS.
    alpha : float
        Exceedance probability per run of this residual.
    min_fit_runs : int
        With fewer samples no fit is made (``basis = "empirical"``).

    Returns
    -------
    dict
        ``basis`` ("gev", "gumbel", "empirical" or "degenerate"), ``quantile`` (of the
        chosen fit, or None), ``gumbel`` and ``gev`` parameters (``xi``, ``mu``,
        ``sigma``, ``loglik``) and their quantiles, ``lr_statistic``, ``empirical_max``,
        ``empirical_quantile`` (None when ``n * alpha < 1``: not estimable from the sample),
        ``extrapolation`` (:math:`1/(n\\alpha)`: how far the quantile lies beyond the
        sample's own return period), ``n``.

    Notes
    -----
    The sample is standardised (:math:`z = (x - \\bar x)/s`). The Gumbel is the maximum
    likelihood fit (``scipy.stats.gumbel_r.fit``); the GEV maximises the log-likelihood
    plus the Coles-Dixon log-penalty (:func:`coles_dixon_penalty`), by Nelder-Mead from the
    Gumbel fit (plain maximum likelihood of a three-parameter GEV on a few tens of maxima
    often returns :math:`\\xi > 1` and absurd quantiles). The GEV is preferred only if the
    likelihood ratio :math:`2(\\ell_\\mathrm{GEV} - \\ell_\\mathrm{Gumbel})` exceeds
    :math:`\\chi^2_{1;0.95} = 3.84`.
    """
    from scipy import optimize, stats

    x = np.asarray(x, dtype=float)
    n = int(x.size)
    p = 1.0 - alpha
    out = {"n": n, "alpha": alpha, "empirical_max": float(x.max()),
           "empirical_quantile": float(np.quantile(x, p)) if n * alpha >= 1 else None,
           "extrapolation": 1.0 / (n * alpha), "quantile": None, "gumbel": None,
           "gev": None, "lr_statistic": None}
    centre, scale = float(x.mean()), float(x.std(ddof=1)) if n > 1 else 0.0
    if not np.all(np.isfinite(x)) or scale <= 1e-12 * max(abs(centre), 1e-300):
        out["basis"] = "degenerate"
        return out
    if n < min_fit_runs:
        out["basis"] = "empirical"
        return out
    z = (x - centre) / scale
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        loc_g, sc_g = stats.gumbel_r.fit(z)
        ll_g = _gev_loglik(z, 0.0, loc_g, sc_g)

        def cost(theta):
            xi, mu, ls = theta
            if xi <= -1.0:
                return 1e300
            val = _gev_loglik(z, xi, mu, math.exp(ls)) + coles_dixon_penalty(xi)
            return -val if np.isfinite(val) else 1e300

        best = None
        for xi0 in (0.0, 0.2, -0.2):
            r = optimize.minimize(cost, [xi0, loc_g, math.log(sc_g)], method="Nelder-Mead",
                                  options={"xatol": 1e-8, "fatol": 1e-10, "maxiter": 4000})
            if r.fun < 1e299 and (best is None or r.fun < best.fun):
                best = r
    gum = {"xi": 0.0, "mu": centre + scale * loc_g, "sigma": scale * sc_g, "loglik": ll_g}
    gum["quantile"] = gev_quantile(p, 0.0, gum["mu"], gum["sigma"])
    out["gumbel"] = gum
    out["basis"] = "gumbel"
    out["quantile"] = gum["quantile"]
    if best is not None:
        xi, mu, ls = (float(v) for v in best.x)
        ll = _gev_loglik(z, xi, mu, math.exp(ls))
        gev = {"xi": xi, "mu": centre + scale * mu, "sigma": scale * math.exp(ls),
               "loglik": ll, "penalised": True}
        gev["quantile"] = gev_quantile(p, xi, gev["mu"], gev["sigma"])
        out["gev"] = gev
        out["lr_statistic"] = max(2.0 * (ll - ll_g), 0.0)
        if out["lr_statistic"] > LR_CRITICAL and np.isfinite(gev["quantile"]):
            out["basis"] = "gev"
            out["quantile"] = gev["quantile"]
    return out


def round_up(value: float, digits: int = 3) -> tuple[float, str]:
    """``value`` rounded *up* to ``digits`` significant digits, and its TOML text.

    Numbers in [0.1, 100) print plainly (``0.35``), others as ``1.43e-4`` / ``2.1e3``.
    """
    if not (value > 0 and math.isfinite(value)):
        raise FdigenError(f"cannot write threshold {value!r}")
    m, e = f"{value:.{digits - 1}e}".split("e")
    mant, exp = Decimal(m), int(e)
    if float(mant.scaleb(exp)) < value:
        mant += Decimal(1).scaleb(-(digits - 1))
        if mant >= 10:
            mant, exp = mant / 10, exp + 1
    v = float(mant.scaleb(exp))
    if 0.1 <= v < 100:
        text = repr(v)
    else:
        ms = f"{mant:f}".rstrip("0")
        text = f"{ms}0e{exp}" if ms.endswith(".") else f"{ms}e{exp}"
    return v, text


def design_thresholds(names, maxima, current: dict, settings: TuneSettings,
                      startup=None) -> dict:
    """Tuned threshold per residual from the healthy per-run maxima.

    Parameters
    ----------
    names : sequence of str
        Residual names (column order of ``maxima``).
    maxima : array_like, shape (runs, residuals)
        Per-run maxima :math:`M_i` of the RMS after settling.
    current : dict
        The model file's thresholds (reported, and kept for residuals the healthy runs
        never excite).
    settings : TuneSettings
    startup : array_like, optional
        Per-run start-up maxima :math:`S_i` (before settling): no threshold is set below
        them (the core flags from the first sample).

    Returns
    -------
    dict
        ``alpha_per_residual``, ``thresholds`` (name -> value written), ``text`` (name ->
        TOML literal), ``residuals`` (name -> statistics), ``fitted_false_alarm``
        (:math:`1 - \\prod_i F_i(J_i)`, None when any residual is empirical),
        ``empirical_false_alarm_in_sample``, ``basis``.
    """
    maxima = np.asarray(maxima, dtype=float)
    n_r = len(names)
    alpha = settings.false_alarm_rate
    alpha_i = 1.0 - (1.0 - alpha) ** (1.0 / n_r)
    out = {"alpha_per_run": alpha, "alpha_per_residual": alpha_i, "margin": settings.margin,
           "runs": int(maxima.shape[0]), "residuals": {}, "thresholds": {}, "text": {}}
    survive = 1.0
    fitted_ok = True
    for j, name in enumerate(names):
        fit = fit_maxima(maxima[:, j], alpha_i, settings.min_fit_runs)
        if name in settings.keep:
            value, text = float(current[name]), None
            fit["note"] = "kept as in the model file (--keep)"
            fit["kept"] = True
        elif fit["basis"] == "degenerate" and fit["empirical_max"] <= 0:
            value, text = float(current[name]), None
            fit["note"] = "never excited by healthy runs: current threshold kept"
            fitted_ok = False
        else:
            base = fit["empirical_max"] if fit["quantile"] is None else max(
                fit["quantile"], fit["empirical_max"])
            if startup is not None:
                su = float(np.max(np.asarray(startup)[:, j]))
                fit["startup_sets_threshold"] = su > base
                base = max(base, su)
            value, text = round_up(settings.margin * base)
        chosen = fit.get(fit["basis"]) if fit["basis"] in ("gev", "gumbel") else None
        if chosen is None:
            fitted_ok = False
        else:
            p_exc = 1.0 - gev_cdf(value, chosen["xi"], chosen["mu"], chosen["sigma"])
            fit["fitted_exceedance_at_threshold"] = p_exc
            survive *= 1.0 - p_exc
        fit["threshold"] = value
        fit["current"] = float(current[name])
        fit["ratio_to_current"] = value / float(current[name])
        if startup is not None:
            fit["startup_max"] = float(np.max(np.asarray(startup)[:, j]))
        seen = max(fit["empirical_max"], fit.get("startup_max", 0.0))
        if value <= seen:
            fit["warning"] = f"threshold {value:g} is below a healthy RMS seen ({seen:g})"
        out["residuals"][name] = fit
        out["thresholds"][name] = value
        out["text"][name] = text or _literal(value)
    J = np.array([out["thresholds"][n] for n in names])
    whole = maxima if startup is None else np.maximum(maxima, np.asarray(startup, dtype=float))
    out["empirical_false_alarm_in_sample"] = float(np.mean(np.any(whole > J, axis=1)))
    out["fitted_false_alarm"] = (1.0 - survive) if fitted_ok else None
    bases = {f["basis"] for f in out["residuals"].values()}
    out["basis"] = ("empirical (too few runs for an extreme-value fit)"
                    if "empirical" in bases else "extreme-value fit")
    return out


def _literal(value: float) -> str:
    if value > 0 and math.isfinite(value):
        v, text = round_up(value, 3)
        if v == value:
            return text
    return repr(float(value))


def clopper_pearson_upper(k: int, n: int, level: float = 0.95) -> float:
    """One-sided upper confidence bound of a binomial proportion (``k`` of ``n``)."""
    from scipy import stats

    if n == 0:
        return 1.0
    if k >= n:
        return 1.0
    return float(stats.beta.ppf(level, k + 1, n - k))


# -- fault campaign summary --------------------------------------------------------------
def _stats(values) -> dict:
    v = [x for x in values if x is not None]
    if not v:
        return {"n": 0, "min": None, "median": None, "max": None}
    return {"n": len(v), "min": float(np.min(v)), "median": float(np.median(v)),
            "max": float(np.max(v))}


def _count(items) -> dict:
    out = {}
    for x in items:
        out[x] = out.get(x, 0) + 1
    return dict(sorted(out.items()))


def summarise_faults(results: list[dict]) -> dict:
    """Per fault: detection and isolation over the campaign, and per size.

    Returns
    -------
    dict
        fault -> ``class``, ``runs``, ``detected``, ``missed``, ``detection_delay``
        (``n``/``min``/``median``/``max`` in s), ``isolated_correct``,
        ``false_isolations``, ``not_isolated``, ``isolation_delay``,
        ``false_alarms_before_onset``, ``off_signature`` and
        ``off_signature_before_isolation`` (residual -> runs in which a residual outside
        the fault's structural signature was raised, at all / before the isolation was
        confirmed: the latter block isolation), ``by_size`` (list of the same per size).
    """
    out = {}
    by_fault = {}
    for r in results:
        by_fault.setdefault(r["fault"], []).append(r)

    def block(rs):
        return {
            "runs": len(rs),
            "detected": sum(r["detected"] for r in rs),
            "missed": sum(not r["detected"] for r in rs),
            "detection_delay": _stats([r["detection_delay"] for r in rs]),
            "isolated_correct": sum(r["isolation_correct"] for r in rs),
            "false_isolations": sum(r["isolated"] not in ("none", r["fault_class"])
                                    for r in rs),
            "not_isolated": sum(r["isolated"] == "none" for r in rs),
            "isolation_delay": _stats([r["isolation_delay"] for r in rs
                                       if r["isolation_correct"]]),
            "false_alarms_before_onset": sum(r["false_alarm_before_onset"] for r in rs),
            "isolated_as": sorted({r["isolated"] for r in rs}),
            "off_signature_before_isolation": _count(
                [x for r in rs for x in r.get("off_signature_before_isolation", ())]),
            "off_signature": _count([x for r in rs for x in r.get("off_signature", ())]),
        }

    for name, rs in by_fault.items():
        entry = {"class": rs[0]["fault_class"], "ramp": rs[0]["ramp"], **block(rs)}
        sizes = []
        for size in sorted({r["size"] for r in rs}, key=abs):
            sub = [r for r in rs if r["size"] == size]
            sizes.append({"size": size, "factor": sub[0]["factor"], **block(sub)})
        entry["by_size"] = sizes
        out[name] = entry
    return out


# -- the model file ----------------------------------------------------------------------
def thresholds_snippet(thresholds: dict, current: dict | None = None,
                       text: dict | None = None) -> str:
    """The ``[fdi.thresholds]`` table as TOML (with the current values as comments)."""
    lines = ["[fdi.thresholds]"]
    for name, value in thresholds.items():
        lit = (text or {}).get(name) or _literal(value)
        note = "" if current is None or name not in current else f"  # was {current[name]:g}"
        lines.append(f"{name} = {lit}{note}")
    return "\n".join(lines) + "\n"


def updated_model_text(text: str, thresholds: dict, literals: dict | None = None) -> str:
    """``text`` (a model file) with the ``[fdi.thresholds]`` values replaced.

    Uses tomlkit: comments, key order and layout are kept, and the comment column of each
    changed line stays where it was when there is room.
    """
    import tomlkit
    from tomlkit.items import Float, Trivia

    doc = tomlkit.parse(text)
    try:
        table = doc["fdi"]["thresholds"]
    except KeyError:
        raise FdigenError("the model file has no [fdi.thresholds] table")
    for name, value in thresholds.items():
        lit = (literals or {}).get(name) or _literal(float(value))
        if name in table and float(table[name]) == float(lit):
            continue            # unchanged: keep the file's own spelling
        if name in table:
            old = table[name]
            t = old.trivia
            trivia = Trivia(indent=t.indent, comment_ws=t.comment_ws, comment=t.comment,
                            trail=t.trail)
            if trivia.comment:
                width = len(old.as_string()) + len(trivia.comment_ws)
                trivia.comment_ws = " " * max(width - len(lit), 1)
            table[name] = Float(float(lit), trivia, lit)
        else:
            table[name] = Float(float(lit), Trivia(), lit)
    return tomlkit.dumps(doc)


def write_thresholds(path, thresholds: dict, literals: dict | None = None,
                     dry_run: bool = False) -> str:
    """Update the ``[fdi.thresholds]`` table of the model file at ``path`` in place.

    Returns the unified diff of the change (written only without ``dry_run``).
    """
    path = Path(path)
    old = path.read_text()
    new = updated_model_text(old, thresholds, literals)
    diff = "".join(difflib.unified_diff(old.splitlines(True), new.splitlines(True),
                                        f"a/{path.name}", f"b/{path.name}"))
    if not dry_run and new != old:
        tmp = path.with_name(path.name + ".tune.tmp")
        tmp.write_text(new)
        tmp.replace(path)
    return diff


def design_with_thresholds(model, thresholds: dict):
    """The FDI design of ``model`` with ``[fdi.thresholds]`` replaced (rebuilt, cached)."""
    from fdigen.design.cache import cached_design

    fdi = dict(model.fdi)
    fdi["thresholds"] = {**dict(fdi.get("thresholds", {})),
                         **{k: float(v) for k, v in thresholds.items()}}
    return cached_design(dataclasses.replace(model, fdi=fdi))


# -- the whole procedure -----------------------------------------------------------------
def tune(model=None, settings: TuneSettings | None = None, *, workers: int = 2,
         scheduler: str | None = None, progress: bool = True, log=None, plant=None,
         plant_effects=()) -> dict:
    """Tune the thresholds of a model: healthy campaign, fit, fault campaign.

    Parameters
    ----------
    model : str, Path or None
        Model file or built-in model name (default: the pneumatic cylinder).
    settings : TuneSettings, optional
    workers : int
        Local Dask worker processes (ignored with ``scheduler``).
    scheduler : str, optional
        Address of a running Dask scheduler, or ``"synchronous"`` to run in-process.
    progress : bool
        Progress bars on stderr.
    log : callable, optional
        ``log(message)`` for stage messages.
    plant : str, Path or Model, optional
        The model simulated as the plant (default: ``model`` itself). A design is tuned
        for the plant it will watch: ``fdigen discover``'s augmented model is tuned on the
        plant that carries the effect, and so is the original design it is compared with
        (``scripts/discover_payoff.py``).
    plant_effects : sequence of fdigen.sim.plant.Effect
        Effects switched on in the simulated plant (terms its model file lacks).

    Returns
    -------
    dict
        The report (JSON-able): settings, thresholds (current and tuned, per-residual
        statistics), false-alarm estimates, fault table, per-run summaries, timing.
    """
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    settings = settings or TuneSettings()
    say = log or (lambda msg: None)
    t_start = time.perf_counter()
    path = resolve_model_path(model)
    m = load_model(path)
    if not m.faults and settings.faults:
        raise FdigenError("the model has no faults")
    design0 = cached_design(m)
    # tuned: the residuals whose thresholds the model file's [fdi.thresholds] sets; others
    # (e.g. measurement-validity indicators) have thresholds fixed by the design
    names = [n for n in design0.residual_names if n in design0.config.thresholds]
    fixed = {n: float(v) for n, v in zip(design0.residual_names,
                                         design0.evaluation.thresholds) if n not in names}
    current = {n: float(design0.config.thresholds[n]) for n in names}
    unknown = sorted(set(settings.keep) - set(names))
    if unknown:
        raise FdigenError(f"--keep names unknown residual(s) {', '.join(unknown)} "
                          f"(residuals: {', '.join(names)})")
    dt = design0.config.sample_time
    settle = design0.config.window * dt if settings.settle is None else settings.settle
    settle_samples = int(round(settle / dt))
    if plant is not None and not hasattr(plant, "states"):
        plant = load_model(resolve_model_path(plant))
    cases = make_cases(m, settings, plant, plant_effects)
    say(f"{m.name}: {len(names)} residuals, {settings.runs} healthy runs of "
        f"{settings.duration:g} s, {len(cases['validation'])} validation runs, "
        f"{len(cases['fault'])} fault runs")
    healthy_design = design_with_thresholds(m, {n: NO_FLAG for n in names})
    timing = {}
    with CampaignExecutor(workers, scheduler, progress) as ex:
        say(f"executor: {ex.description}")
        t0 = time.perf_counter()
        ex.warm_up(healthy_design)
        timing["warm_up"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        healthy = ex.run(healthy_design, cases["healthy"], settle_samples, "healthy runs")
        timing["healthy"] = time.perf_counter() - t0
        maxima = np.array([[r["max_rms"][n] for n in names] for r in healthy])
        startup = np.array([[r["max_rms_startup"][n] for n in names] for r in healthy])
        tuned = design_thresholds(names, maxima, current, settings, startup)
        say("deriving the design with the tuned thresholds")
        t0 = time.perf_counter()
        tuned_design = design_with_thresholds(m, tuned["thresholds"])
        timing["rebuild_design"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        rest = ex.run(tuned_design, cases["validation"] + cases["fault"], settle_samples,
                      "validation + fault runs") if (cases["validation"] or cases["fault"]) \
            else []
        timing["validation_and_faults"] = time.perf_counter() - t0
        executor = ex.description
    # cases were indexed per kind: split back by kind
    validation = [r for r in rest if r["kind"] == "validation"]
    fault_runs = [r for r in rest if r["kind"] == "fault"]
    k_val = sum(r["t_first_flag"] is not None for r in validation)
    fa = {
        "target_per_run": settings.false_alarm_rate,
        "run_duration": settings.duration,
        "basis": tuned["basis"],
        "fitted": tuned["fitted_false_alarm"],
        "empirical_in_sample": tuned["empirical_false_alarm_in_sample"],
        "validation_runs": len(validation),
        "validation_false_alarms": k_val,
        "validation_upper_95": clopper_pearson_upper(k_val, len(validation)),
        "set_by_startup": [n for n in names
                           if tuned["residuals"][n].get("startup_sets_threshold")],
        "healthy_runs_current_thresholds_exceeded": int(np.sum(np.any(
            maxima > np.array([current[n] for n in names]), axis=1))),
    }
    runs = healthy + validation + fault_runs
    samples = sum(r["samples"] for r in runs)
    sim_s = sum(r["timing"].get("simulate", 0.0) for r in runs)
    fdi_s = sum(r["timing"].get("fdi", 0.0) for r in runs)
    cpu_s = sum(r["timing"].get("simulate_cpu", 0.0) + r["timing"].get("fdi_cpu", 0.0)
                for r in runs)
    timing.update({"total": time.perf_counter() - t_start, "samples": samples,
                   "task_simulate_seconds": sim_s, "task_fdi_seconds": fdi_s,
                   "task_cpu_seconds": cpu_s,
                   "samples_per_second_per_core": samples / (sim_s + fdi_s) if sim_s else None,
                   "samples_per_cpu_second": samples / cpu_s if cpu_s else None})
    return {
        "model": m.name, "model_file": str(path), "residuals": names,
        "plant": None if plant is None else plant.source,
        "plant_effects": [{"effect": e.name, "target": e.target,
                           "parameters": dict(e.parameters)} for e in plant_effects],
        "fixed_residuals": fixed,
        "settings": {**dataclasses.asdict(settings), "settle": settle,
                     "settle_samples": settle_samples,
                     "uncertain_parameters": [q.name for q in m.parameters if q.uncertain]},
        "executor": executor,
        "current_thresholds": current,
        "thresholds": tuned["thresholds"],
        "threshold_text": tuned["text"],
        "threshold_statistics": tuned,
        "false_alarm": fa,
        "faults": summarise_faults(fault_runs),
        "runs": {"healthy": healthy, "validation": validation, "fault": fault_runs},
        "timing": timing,
    }
