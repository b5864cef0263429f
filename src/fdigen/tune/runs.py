"""One task: simulate a closed-loop run, evaluate it with the C FDI core, summarise it.

Holds the per-process cache of compiled cores (:func:`_runner`), :func:`run_case` (the
function the Dask workers run; importable at module level so it pickles by reference) and
:func:`summarise_case` (the small per-run summary: RMS maxima, flags, isolation, delays).
"""

from __future__ import annotations

import time

import numpy as np

from fdigen.tune.cases import simulate_case
from fdigen.tune.run_notes import late_start
from fdigen.tune.settings import Case

_RUNNERS: dict = {}      # id(design) -> (design, runner): the scattered object, per task
_BY_CONTENT: dict = {}   # model hash (thresholds included) -> runner


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
        from fdigen.sim.plant import FaultEvent

        faults = () if case.fault is None else (FaultEvent(*case.fault),)
        runner = _runner(design)
        t0, c0 = time.perf_counter(), time.process_time()
        sim = simulate_case(design.model, case, faults)
        t1, c1 = time.perf_counter(), time.process_time()
        out = runner.run(sim.u, sim.y)
        t2, c2 = time.perf_counter(), time.process_time()
        res = summarise_case(design, case, sim.t, out, settle_samples,
                             timing={"simulate": t1 - t0, "fdi": t2 - t1,
                                     "simulate_cpu": c1 - c0, "fdi_cpu": c2 - c1})
        res["not_real"] = sim.first_not_real()    # the plant left its equations' domain
        return res
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
    s0 = min(int(ev.startup), s)     # the core's start-up: no flag can rise before it
    res = {"kind": case.kind, "index": case.index, "seed": case.seed,
           "parameters": case.parameters, "ref_scale": case.ref_scale,
           "ref_shift": case.ref_shift, "samples": int(K),
           "max_rms": dict(zip(ev.residuals, rms[s:].max(axis=0).tolist())),
           "t_max": dict(zip(ev.residuals, (float(t[s + k])
                                            for k in rms[s:].argmax(axis=0)))),
           "max_rms_startup": dict(zip(ev.residuals, (rms[s0:s].max(axis=0) if s > s0 else
                                                      np.zeros(rms.shape[1])).tolist())),
           # the last third of the run: a healthy maximum far above it came early
           "max_rms_late": dict(zip(ev.residuals,
                                    rms[max(s, late_start(K)):].max(axis=0).tolist())),
           "timing": timing or {}}
    res.update(settling(rms, t))
    on = np.flatnonzero(flags)
    res["t_first_flag"] = float(t[on[0]]) if on.size else None
    res["flags_raised"] = [ev.residuals[i] for i in range(len(ev.residuals))
                           if flags[-1] >> i & 1]
    res["t_raised"] = {name: float(t[np.flatnonzero(flags >> i & 1)[0]])
                       for i, name in enumerate(ev.residuals) if flags[-1] >> i & 1}
    # a class isolated (unexplained is an escalation, not a class: counted apart)
    iso = np.flatnonzero((cls > 0) & (cls != ev.unexplained))
    res["isolated"] = ev.classes[int(cls[iso[0]])] if iso.size else "none"
    res["t_isolated"] = float(t[iso[0]]) if iso.size else None
    esc = np.flatnonzero(cls == ev.unexplained)
    res["t_unexplained"] = float(t[esc[0]]) if esc.size else None
    act = np.asarray(out["action"], dtype=np.int64) if "action" in out else np.zeros(K, int)
    took = np.flatnonzero(act)
    res["t_action"] = float(t[took[0]]) if took.size else None
    res["action"] = int(act[-1]) if K else 0
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
        res.update(_fault_level(design, name, out, flags, iso, k0, t, res))
    return res


#: Points of the first third of a run at which :func:`settling` keeps the RMS maxima
#: after them.
SUFFIX_POINTS = 32


def settling(rms, t) -> dict:
    """How a run's residuals come down from the core's start.

    ``t_settled``: per residual, the time from the run's start after which its RMS stays
    within :data:`~fdigen.tune.run_notes.SETTLED_FACTOR` of its maximum over the
    last third (``None`` when it is above that at the end of the first third: not a
    start-up); ``suffix_max``: the times ``t_j`` (``SUFFIX_POINTS + 1`` points over the
    first third) and per residual :math:`\\max_{k \\ge k_j} \\mathrm{RMS}[k]`, from
    which a start-up's thresholds are fitted without running again.
    """
    from fdigen.tune.run_notes import SETTLED_FACTOR, late_start

    rms, t = np.asarray(rms, dtype=float), np.asarray(t, dtype=float)
    K, n = rms.shape
    if K < 6:
        return {"t_settled": {}, "suffix_max": {"t": [], "max": []}}
    level = SETTLED_FACTOR * rms[late_start(K):].max(axis=0)
    settled = []
    for i in range(n):
        above = np.flatnonzero(rms[:, i] > level[i])
        settled.append(0.0 if not above.size else (float(t[above[-1] + 1] - t[0])
                                                   if above[-1] + 1 < K // 3 else None))
    after = np.maximum.accumulate(rms[::-1], axis=0)[::-1]
    points = np.unique(np.linspace(0, K // 3, SUFFIX_POINTS + 1).astype(int))
    return {"t_settled": settled,
            "suffix_max": {"t": (t[points] - t[0]).tolist(), "max": after[points].tolist()}}


def _fault_level(design, name, out, flags, iso, k0, t, res) -> dict:
    """Isolation to the fault: the consistent-fault set the core reported (at the class
    decision and at the end, or the last non-empty one), whether it holds the true fault,
    whether it is as narrow as the table allows (the faults with the true fault's
    signature), and each signature entry's delay after the onset."""
    from fdigen.detect import fault_names

    ev = design.evaluation
    cons = (np.asarray(out["faults"], dtype=np.int64) if "faults" in out else
            np.array([ev.consistent_faults(int(f)) for f in flags], dtype=np.int64))
    nonzero = np.flatnonzero(cons[k0:])
    last = fault_names(design, int(cons[k0 + nonzero[-1]])) if nonzero.size else []
    at_iso = fault_names(design, int(cons[iso[0]])) if iso.size and iso[0] >= k0 else []
    sig = design.signature_table[name]
    # as narrow as the table allows from the flags a live sensor raises: a validity flag
    # (nf_<y>) rises only when its sensor dies, so it does not narrow the set (a user's
    # encoder offset shares its other entries with two plant faults: "0/6" had read as
    # a failure of the isolation)
    validity = {f"nf_{o.name}" for o in design.model.outputs}
    # the set the core reports when exactly the fault's signature is raised: the faults
    # whose signature contains it stay consistent (a quarter car's accelerometer bias,
    # {Racc}, leaves the actuator and the damper, {Racc, Rdefl}: "0/4" read as a miss)
    own = sum(1 << ev.residuals.index(r) for r in set(sig) - validity
              if r in ev.residuals)
    best = sorted(fault_names(design, int(ev.consistent_faults(own)))) if own else sorted(
        f for f, s in design.signature_table.items() if set(s) - validity == set(sig) - validity)
    onset = res["t0"]
    return {"faults_at_isolation": at_iso, "faults_consistent": last,
            "fault_consistent": name in last if last else None,
            "fault_isolated": bool(last) and sorted(last) == best,
            "fault_set_best": best,
            "entry_delays": {r: res["t_raised"][r] - onset for r in sorted(sig)
                             if r in res["t_raised"] and res["t_raised"][r] >= onset}}
