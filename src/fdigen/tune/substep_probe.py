"""The campaign's plant sub-steps, checked for accuracy on the runs that stress it.

The campaign's RK4 sub-steps are chosen stable over the tolerance box
(:func:`fdigen.tune.cases.campaign_raise`); a fault at its test size can still take the
plant where that count is not accurate (:mod:`fdigen.sim.substep_accuracy`: a door
opened wide). Before the campaign runs, one run per fault, at its largest step, and the
first healthy run are simulated at that count and at twice it; where they disagree, every
run of the campaign is simulated at the count that agrees with its doubling.
"""

from __future__ import annotations

import dataclasses

from fdigen.tune.settings import Case


def probe_cases(cases: dict[str, list[Case]]) -> list[Case]:
    """The runs :func:`accurate_campaign` simulates twice: the first healthy run and, per
    fault, its run at the largest step (its first onset)."""
    out = cases.get("healthy", [])[:1]
    largest: dict[str, Case] = {}
    for c in cases.get("fault", []):
        name, _, size, ramp = c.fault
        if ramp:
            continue
        if name not in largest or abs(size) > abs(largest[name].fault[2]):
            largest[name] = c
    return out + list(largest.values())


#: Probe results per plant and runs, in this process: tune's searches (realignment,
#: innovation filter, held correction, class decision) run the same campaign again on a
#: model file whose ``[fdi]`` differs and whose plant does not.
_PROBED: dict = {}


def _probe_key(model, probes, start: int) -> tuple:
    """What a probe's result depends on: the simulated plants (their model hash with
    ``[fdi]`` reduced to its sample time, the only key the simulator reads), the runs and
    the start count."""
    import dataclasses as dc

    from fdigen.model.model_file import model_hash

    def plant_id(m):
        return model_hash(dc.replace(m, fdi={"sample_time": m.fdi.get("sample_time")}))

    return (plant_id(model), int(start),
            tuple((None if c.plant is None else plant_id(c.plant),
                   repr(dc.replace(c, plant=None))) for c in probes))


def probe_case(model, case: Case, start: int) -> dict:
    """:func:`fdigen.sim.substep_accuracy.converged_simulation` of one run, without its
    log (a worker's small answer)."""
    from fdigen.sim.plant import FaultEvent
    from fdigen.sim.substep_accuracy import converged_simulation
    from fdigen.tune.cases import simulate_case

    faults = () if case.fault is None else (FaultEvent(*case.fault),)
    acc = converged_simulation(
        case.plant or model,
        lambda n: simulate_case(model, dataclasses.replace(case, substeps=n), faults), start)
    return {"start": acc.start, "used": acc.used, "converged": acc.converged,
            "ratio": acc.ratio, "output": acc.output, "t": acc.t}


def accurate_campaign(model, cases: dict[str, list[Case]], run_all=None):
    """The campaign's cases at a sub-step count that every :func:`probe_cases` run agrees
    with at its doubling (:func:`probe_case`).

    Parameters
    ----------
    model : Model
        The design's model (the simulated plant is each case's ``plant`` when set).
    cases : dict
        :func:`fdigen.tune.cases.make_cases`'s runs.
    run_all : callable, optional
        ``run_all(fn, argument_tuples) -> list`` (a campaign executor's ``map``); default
        in this process.

    Returns
    -------
    (dict, dict or None)
        The cases (with ``substeps`` raised where needed) and ``None`` when their count
        was accurate, else ``start``, ``used``, ``converged``, ``case`` (the run that
        needed the most), ``ratio`` and ``text``.
    """
    from fdigen.sim.substep_accuracy import SubstepAccuracy
    from fdigen.sim.substeps import simulation_substeps

    probes = probe_cases(cases)
    if not probes:
        return cases, None
    plant = probes[0].plant or model
    start = probes[0].substeps or simulation_substeps(
        plant, float(plant.fdi.get("sample_time", 1e-3)))
    run_all = run_all or (lambda fn, items: [fn(*a) for a in items])
    key = _probe_key(model, probes, start)
    found = _PROBED.get(key)
    if found is None:
        found = run_all(probe_case, [(model, c, start) for c in probes])
        if len(_PROBED) > 16:
            _PROBED.clear()
        _PROBED[key] = found
    k = max(range(len(found)), key=lambda i: (found[i]["used"], not found[i]["converged"]))
    acc, case = SubstepAccuracy(result=None, **found[k]), probes[k]
    if acc.converged and not acc.raised:
        return cases, None
    what = ("the healthy run" if case.fault is None else
            f"{case.fault[0]} at {case.fault[2]:g} from {case.fault[1]:g} s")
    info = {"start": acc.start, "used": acc.used, "converged": acc.converged,
            "ratio": acc.ratio, "case": what, "output": acc.output,
            "text": acc.text(what) + "; every run of the campaign is simulated at "
            + str(acc.used)}
    raised = {kind: [dataclasses.replace(c, substeps=acc.used) for c in runs]
              for kind, runs in cases.items()}
    return raised, info
