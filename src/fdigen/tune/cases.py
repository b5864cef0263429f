"""Case generation: every run of the campaigns, drawn reproducibly from the master seed.

Holds the parameter spread (:func:`perturbed_parameters`), the varied demand
(:func:`demand_expression`, its centre :func:`_reference_centre`), the fault sizes of a
fault (:func:`_fault_sizes`) and :func:`make_cases`, which draws the healthy, validation
and fault runs.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np

from fdigen.errors import FdigenError
from fdigen.tune.settings import Case, TuneSettings


def perturbed_parameters(model, rng, tolerance: float, per: dict | None = None) -> dict:
    """Uncertain parameters drawn uniformly in :math:`p_0 (1 \\pm \\mathrm{tol})`, clipped
    to their bounds; ``per`` gives some parameters their own ``tol``."""
    out = {}
    for q in model.parameters:
        if q.uncertain:
            tol = (per or {}).get(q.name, tolerance)
            v = q.value * (1.0 + rng.uniform(-tol, tol))
            if q.bounds is not None:
                v = min(max(v, q.bounds[0]), q.bounds[1])
            out[q.name] = float(v)
    return out


#: Uncertain parameters up to which every vertex of the tolerance box is a run (2^k runs);
#: beyond, the 2k axis extremes and the two vertices of all-equal signs.
MAX_FULL_VERTEX_PARAMETERS = 4
#: Beyond this many, only the two corners of equal signs (26 runs at most).
MAX_AXIS_VERTEX_PARAMETERS = 12


def tolerance_vertices(model, tolerance: float, per: dict | None = None) -> list[dict]:
    """Parameter sets at the vertices of the declared tolerance box.

    .. math:: p_j = p_{j,0} (1 + s_j\\,\\mathrm{tol}_j),\\qquad s \\in \\{-1, 1\\}^k

    for the ``k`` uncertain parameters (clipped to their bounds): all :math:`2^k` when
    ``k <= MAX_FULL_VERTEX_PARAMETERS``, else each parameter at either end with the others
    nominal plus the two vertices of equal signs (``2k + 2`` sets), and beyond
    ``MAX_AXIS_VERTEX_PARAMETERS`` those two alone. A residual's healthy
    RMS that grows with a parameter's error is largest at a vertex: the uniform draws of
    the healthy campaign reach one rarely (a maglev coil 9 % warm, inside its 10 %, raised
    a current residual 1.3x over a threshold eight random runs had set).
    """
    import itertools

    unc = [q for q in model.parameters if q.uncertain]
    tol = [(per or {}).get(q.name, tolerance) for q in unc]
    if not unc or not any(t > 0 for t in tol):
        return []
    k = len(unc)
    if k <= MAX_FULL_VERTEX_PARAMETERS:
        signs = list(itertools.product((-1.0, 1.0), repeat=k))
    elif k > MAX_AXIS_VERTEX_PARAMETERS:       # a bounded number of runs: 33 uncertain
        signs = [(-1.0,) * k, (1.0,) * k]      # parameters made 68 per campaign
    else:
        signs = [tuple(float(s) if i == j else 0.0 for i in range(k))
                 for j in range(k) for s in (-1, 1)] + [(-1.0,) * k, (1.0,) * k]
    out = []
    for sg in signs:
        pars = {}
        for q, t, s in zip(unc, tol, sg):
            v = q.value * (1.0 + s * t)
            if q.bounds is not None:
                v = min(max(v, q.bounds[0]), q.bounds[1])
            pars[q.name] = float(v)
        if pars not in out:
            out.append(pars)
    return out


#: Most points :func:`_reference_centre` evaluates the demand at.
CENTRE_POINTS = 200_000


def _reference_centre(model, horizon: float = 200.0) -> float:
    """Mean of the demand over ``horizon`` seconds: 100 samples per second, at most
    ``CENTRE_POINTS`` (a digester's 20-day runs averaged over 200 days at 0.01 s asked
    for 1.7e9 points, 12.9 GiB, and tune died of it)."""
    from fdigen.sim.plant import reference_signal

    step = max(0.01, float(horizon) / CENTRE_POINTS)
    return float(np.mean(reference_signal(model, np.arange(0.0, horizon, step))))


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


def varied_simulation(model, scale: float, shift: float, centres: dict) -> dict:
    """The ``[simulation]`` table with every demand varied as :func:`demand_expression`.

    The single-loop form replaces ``reference``; the several-loops form replaces each
    controller's ``reference`` (scaled about its own mean). ``centres`` caches the means
    by ``(model name, reference text)``.
    """
    from fdigen.model.simulation_spec import simulation_spec

    spec = simulation_spec(model)
    if spec.legacy:
        key = (model.name, model.simulation.get("reference"))
        if key not in centres:
            centres[key] = _reference_centre(model)
        return {**model.simulation,
                "reference": demand_expression(model, scale, shift, centres[key])}
    controllers = {name: dict(table)
                   for name, table in model.simulation["controllers"].items()}
    for c in spec.controllers:
        if c.reference is None:
            continue
        single = dataclasses.replace(model, simulation={
            "input": c.input, "controller": "0", "reference": c.reference})
        key = (model.name, c.reference)
        if key not in centres:  # slow plants have slow demands: average over 10 runs
            horizon = max(200.0, 10.0 * float(model.simulation.get("duration", 20.0)))
            centres[key] = _reference_centre(single, horizon)
        controllers[c.name]["reference"] = demand_expression(single, scale, shift,
                                                             centres[key])
    return {**model.simulation, "controllers": controllers}


def _fault_sizes(fault, factors):
    sizes = []
    for k in factors:
        s = float(k) * fault.test_size
        if fault.mode == "multiplicative" and abs(float(fault.test_size)) <= 1.0:
            # a loss written as a fraction goes no further than 100 %; a fault whose own
            # test size is beyond 1 is a growth (a capacitor's ESR x4: test_size 3), and
            # was run at 1 without a word
            s = float(np.clip(s, -1.0, 1.0))
        if all(abs(s - t) > 1e-12 * max(1.0, abs(s)) for t, _ in sizes):
            sizes.append((s, float(k)))
    return sizes


def clipped_sizes(model, factors, faults=None) -> list[str]:
    """A note per multiplicative fault whose campaign sizes were clipped at a total loss
    (``|size| <= 1`` with a test size within 1): the factors asked that were not run. A
    pump's bearing friction (test size 1) ran at 0.25, 0.5 and 1 of 0.25, 0.5, 1 and 2,
    and nothing said why (round 41)."""
    out = []
    for f in model.faults:
        if faults is not None and f.name not in faults:
            continue
        run = {k for _, k in _fault_sizes(f, factors)}
        lost = [float(k) for k in dict.fromkeys(float(x) for x in factors) if k not in run]
        if lost:
            out.append(f"{f.name}: sizes {', '.join(f'{k:g}x' for k in lost)} its test size "
                       f"({f.test_size:g}) not run: a multiplicative fault of a test size "
                       "within 1 is read as a loss, which stops at 1 (a total loss); a "
                       "fault that grows (a friction doubling) is written with a test size "
                       "above 1")
    return out


def plant_time_scale(model) -> float:
    """The plant's slowest time constant at the operating point [s].

    .. math:: \\tau = \\max_i 1/|\\mathrm{Re}\\,\\lambda_i(A)|

    over the eigenvalues of the linearisation ``A = df/dx`` that are not on the imaginary
    axis (integrators and undamped modes have no time constant); 0 when there are none.
    """
    from fdigen.derive.linearisation import linearise

    re = np.abs(np.linalg.eigvals(linearise(model).A).real)
    re = re[re > 1e-9 * max(float(re.max(initial=0.0)), 1e-300)]
    return float(1.0 / re.min()) if re.size else 0.0


def ramp_rate(model, fault, window_time: float, span: float | None = None) -> float:
    """Rate of the campaign's drift case of an additive sensor fault [units/s].

    The fault's ``test_rate`` when the model file declares one; otherwise the drift that
    reaches ``test_size`` after the plant's slowest time constant (:func:`plant_time_scale`),
    or within half of ``span`` (the run's time left after the fault's onset: the other
    half is left for its detection) when that is shorter, and never faster than over one
    RMS window (``window_time``):

    .. math:: \\dot s = s_{test} / \\max(\\min(\\tau, T_{span}/2), N\\,\\Delta t)

    (A rate of ``test_size`` per second made slow plants' drifts absurd: a 2 cm level
    offset as 2 cm/s on tanks of 500 s; a rate over a time constant longer than the run
    made them absurd the other way: an HVAC zone of 38,000 s drifted 5 % of its test size
    in a 3600 s run.)
    """
    if fault.test_rate is not None:
        return float(fault.test_rate)
    tau = plant_time_scale(model)
    if span is not None and span > 0:
        tau = min(tau, span / 2) if tau > 0 else span / 2
    return float(fault.test_size) / max(tau, window_time)


def test_size_specs(model, window_time: float, span: float | None = None) -> list:
    """``(fault, size, ramp)`` of every declared fault at its test size (a step), and of
    every additive sensor fault also as a drift at its :func:`ramp_rate` (reaching its
    test size within ``span`` seconds, the run's time after the onset)."""
    out = []
    for f in model.faults:
        out += [(f.name, size, False) for size, _ in _fault_sizes(f, (1.0,))]
        if f.location == "sensor" and f.mode == "additive":
            out.append((f.name, ramp_rate(model, f, window_time, span), True))
    return out


#: reference means of the varied demands (:func:`varied_simulation`), per process
_CENTRES: dict = {}


def simulate_case(model, case, faults=()):
    """The closed-loop run of ``case``: its plant (``case.plant``, else ``model``), its
    demand variation, parameter spread, noise seed and effects, with ``faults``
    (:class:`fdigen.sim.plant.FaultEvent`) switched on."""
    from fdigen.sim.plant import simulate

    plant = model if case.plant is None else case.plant
    sim_model = dataclasses.replace(plant, simulation=varied_simulation(
        plant, case.ref_scale, case.ref_shift, _CENTRES))
    return simulate(sim_model, case.duration, faults=tuple(faults),
                    parameters=case.parameters, seed=case.seed, effects=case.effects,
                    substeps=case.substeps)


#: ``make_cases``'s default ``raised``: computed there
_COMPUTED = object()


def make_cases(model, settings: TuneSettings, plant=None,
               effects=(), raised=_COMPUTED) -> dict[str, list[Case]]:
    """Every run of the campaigns, drawn from the master seed (reproducible).

    With ``plant`` (a Model) the runs simulate that model instead of the design's, with
    the extra ``effects`` (:class:`fdigen.sim.plant.Effect`) switched on; the parameter
    spread is drawn around the plant's values. Two designs tuned with the same plant,
    effects and seed see exactly the same runs. ``raised``: the plant's sub-step raise
    (:func:`campaign_raise`) when the caller has it, else computed here.
    """
    sim_model = model if plant is None else plant
    effects = tuple(effects)
    ss = np.random.SeedSequence(settings.seed)
    streams = dict(zip(("healthy", "validation", "fault"), ss.spawn(3)))
    lo, hi = settings.ref_scale

    def draw(kind, n):
        return draw_from(streams[kind], n)

    def draw_from(stream, n):
        rngs = [np.random.default_rng(s) for s in stream.spawn(n)]
        return [(int(r.integers(2**31 - 1)), perturbed_parameters(sim_model, r,
                                                                 settings.tolerance,
                                                                 dict(settings.tolerances)),
                 float(r.uniform(lo, hi)), float(r.uniform(0.0, settings.ref_shift)))
                for r in rngs]

    out = {}
    for kind, n in (("healthy", settings.runs), ("validation", settings.validation_runs)):
        out[kind] = [Case(kind, i, seed, settings.duration, pars, a, tau, plant=plant,
                          effects=effects)
                     for i, (seed, pars, a, tau) in enumerate(draw(kind, n))]
    # the tolerance box's vertices: a stream of their own (the others' draws unchanged)
    vertices = (tolerance_vertices(sim_model, settings.tolerance, dict(settings.tolerances))
                if settings.vertex_runs else [])
    out["vertex"] = [Case("vertex", i, seed, settings.duration, pars, a, tau, plant=plant,
                          effects=effects)
                     for i, (pars, (seed, _, a, tau)) in enumerate(zip(
                         vertices, draw_from(ss.spawn(1)[0], len(vertices))))]
    names = (tuple(f.name for f in model.faults) if settings.faults is None
             else tuple(settings.faults))
    known = {f.name for f in model.faults}
    for name in names:
        if name not in known:
            raise FdigenError(f"unknown fault '{name}' (model faults: {', '.join(sorted(known))})")
    starts = (np.linspace(0.35, 0.65, settings.fault_starts) if settings.fault_starts > 1
              else np.array([0.5])) * settings.duration
    specs = []
    window_time = None
    for name in names:
        f = model.fault(name)
        for size, k in _fault_sizes(f, settings.fault_factors):
            for t0 in starts:
                specs.append(((name, float(round(t0, 3)), size, False), k))
        if f.location == "sensor" and f.mode == "additive":
            # sensor offsets run as steps and as drifts (ramps at their own rate)
            if window_time is None:
                from fdigen.design.config import read_fdi_config
                cfg = read_fdi_config(model)
                window_time = cfg.window * cfg.sample_time
            # the drift reaches its test size before the run ends (latest onset)
            rate = ramp_rate(model, f, window_time, settings.duration - float(starts.max()))
            for k in dict.fromkeys(float(x) for x in settings.fault_factors):
                for t0 in starts:
                    specs.append(((name, float(round(t0, 3)), k * rate, True), k))
    out["fault"] = [Case("fault", i, seed, settings.duration, pars, a, tau, spec, k,
                         plant=plant, effects=effects)
                    for i, ((spec, k), (seed, pars, a, tau))
                    in enumerate(zip(specs, draw("fault", len(specs))))]
    if raised is _COMPUTED:
        raised = campaign_raise(sim_model, settings)
    if raised is None:
        return out
    # the plant's RK4 sub-steps raised to a count stable at every vertex of the box
    return {kind: [dataclasses.replace(c, substeps=raised["used"]) for c in runs]
            for kind, runs in out.items()}


def campaign_raise(plant, settings: TuneSettings) -> dict | None:
    """The campaign's raise of the plant's RK4 sub-steps over its tolerance box
    (:func:`fdigen.sim.substeps.campaign_substeps`), or ``None``."""
    from fdigen.sim.substeps import campaign_substeps

    dt = float(plant.fdi.get("sample_time", 1e-3))
    box = tolerance_vertices(plant, settings.tolerance, dict(settings.tolerances))
    return campaign_substeps(plant, dt, box)
