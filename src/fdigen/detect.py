"""Detection on logs: run the FDI core over a measured log and summarise its decisions."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fdigen.design.fdi_design import FdiDesign


def fdi_runner(design: FdiDesign, backend: str = "auto"):
    """An object with ``run(u, y)`` for the design: the compiled C core by default.

    ``backend`` is ``"c"``, ``"casadi"``, ``"reference"`` or ``"auto"`` (C if a compiler
    works, else the reference).
    """
    if backend in ("auto", "c"):
        try:
            from fdigen.backends.c.loader import CFdi
            return CFdi(design)
        except Exception:
            if backend == "c":
                raise
    if backend == "casadi":
        from fdigen.backends.casadi_backend.runner import CasadiFdi
        return CasadiFdi(design, compiled=True)
    from fdigen.backends.reference import ReferenceFdi
    return ReferenceFdi(design)


def summarise_run(design: FdiDesign, t: np.ndarray, out: dict, log: str = "") -> dict:
    """The decision of a run: when each flag rose, the isolated class, time and action.

    Returns the dict printed by ``fdigen detect --json``.
    """
    ev = design.evaluation
    flags = np.asarray(out["flags"], dtype=np.int64)
    raised = []
    late = int(late_flags(design, flags)[-1]) if len(flags) else 0
    for i, name in enumerate(ev.residuals):
        on = np.flatnonzero((flags >> i) & 1)
        if on.size:
            raised.append({"residual": name, "t_raised": float(t[on[0]]),
                           "late": bool(late >> i & 1)})
    raised.sort(key=lambda f: (f["t_raised"], f["residual"]))
    cls = np.asarray(out["fault_class"])
    iso = np.flatnonzero(cls > 0)
    consistent = _consistent_masks(design, out, flags)
    if iso.size:
        k = int(np.flatnonzero(cls == cls[-1])[0])     # the final decision, when it was made
        diagnosis = {"fault": ev.classes[int(cls[-1])], "t_isolated": float(t[k]),
                     "action": ev.actions[int(cls[-1])],
                     "candidates": fault_names(design, int(consistent[k]))}
    else:
        diagnosis = {"fault": "none", "t_isolated": None, "action": "none",
                     "candidates": []}
    diagnosis.update(consistent_faults_summary(design, consistent))
    diagnosis.update(action_summary(design, t, out, cls))
    diagnosis.update(escalation_summary(design, t, flags, cls))
    k_set = diagnosis.pop("fault_set_sample")
    diagnosis["t_fault_set"] = None if k_set is None else float(t[k_set])
    if not iso.size and raised:
        # ambiguous: the faults still consistent with the flags (never an empty list
        # while one is; see docs/isolation.md)
        diagnosis["candidates"] = diagnosis["consistent_faults"] or \
            diagnosis["last_consistent_faults"]
    named = {design.model.fault(f).fault_class for f in diagnosis["candidates"]}
    diagnosis["named_class"] = (next(iter(named)) if not iso.size and len(named) == 1
                                else None)
    dt = float(f"{np.median(np.diff(t)):.12g}") if len(t) > 1 else float("nan")
    nominal = design.config.sample_time
    if nominal and abs(dt - nominal) <= 0.1 * nominal:
        dt = float(nominal)     # a logger's jitter (a user's 1 s log read "at 0.999 s")
    return {"log": log, "sample_time": dt, "samples": int(len(t)), "flags": raised,
            "diagnosis": diagnosis, "detected": bool(raised),
            **verdict_support(len(t), design.config.window, bool(raised))}


def verdict_support(samples: int, window: int, detected: bool) -> dict:
    """Whether a log of ``samples`` samples supports a verdict: the moving RMS of eq (22)
    averages ``window`` samples, so a shorter log that raised no flag is no evidence of
    health.

    Returns
    -------
    dict
        ``enough_data`` (bool) and ``verdict``: ``"no verdict: ..."`` for a short log
        without flags, a caveat for a short log with flags, else ``"supported"``.
    """
    if samples >= window:
        return {"enough_data": True, "verdict": "supported"}
    why = f"the log has {samples} samples, the window needs {window}"
    if detected:
        return {"enough_data": False,
                "verdict": f"flags raised on a partial window ({why})"}
    return {"enough_data": False, "verdict": f"no verdict: {why}"}


def action_summary(design: FdiDesign, t: np.ndarray, out: dict, cls: np.ndarray) -> dict:
    """The action the core took (latched, never decreasing) and when; and, taken before
    any class was isolated, the classes whose faults were consistent then (``action_basis``
    ``"isolated"``, ``"unanimous"``: every consistent class calls for it, or
    ``"most_severe"``: the ambiguity policy)."""
    ev = design.evaluation
    if "action" not in out or not len(t):
        return {"t_action": None, "action_basis": None, "action_classes": []}
    act = np.asarray(out["action"], dtype=np.int64)
    final = int(act[-1])
    from fdigen.design.config import ACTIONS

    if final == 0:
        return {"action": "none", "t_action": None, "action_basis": None, "action_classes": []}
    k = int(np.flatnonzero(act == final)[0])
    if cls[k] > 0:
        return {"action": ACTIONS[final], "t_action": float(t[k]), "action_basis": "isolated",
                "action_classes": [ev.classes[int(cls[k])]]}
    # the classes the core's action reads: those whose class-level pattern holds every
    # class-deciding flag (a user's pump: the fault-level set said "pump" alone, action
    # none, while the core's class level also held the pressure sensor: accommodate),
    # late flags left out as the core leaves them (a user's battery: a late Rb_p read as
    # evidence made "every consistent class calls for it: coolant_flow" of the ambiguity
    # policy's most severe action)
    flags = np.asarray(out["flags"], dtype=np.int64)
    held = int(flags[k]) & ~int(late_flags(design, flags)[k]) & ev.class_flags
    classes = sorted({ev.classes[c] for mask, c in ev.patterns if held & ~mask == 0})
    if not classes:
        faults = fault_names(design, int(_consistent_masks(design, out, out["flags"])[k]))
        classes = sorted({design.model.fault(f).fault_class for f in faults})
    basis = "unanimous" if len({ev.actions[ev.classes.index(c)] for c in classes}) <= 1 \
        else "most_severe"
    return {"action": ACTIONS[final], "t_action": float(t[k]), "action_basis": basis,
            "action_classes": classes}


def late_flags(design: FdiDesign, flags: np.ndarray) -> np.ndarray:
    r"""The latched mask of late flags at each sample, as the core keeps it: a flag that
    rises more than its validity horizon ``H_i`` samples after the first flag froze the
    parallel models (:func:`fdigen.design.evaluation.late_mask`) is no evidence.

    .. math:: L_k = L_{k-1} \,|\, (F_k \,\&\, \lnot F_{k-1} \,\&\,
              	extstyle\sum_i 2^i [z_k > H_i]),\quad z_k = z_{k-1} + [F_{k-1} 
e 0]
    """
    from fdigen.design.evaluation import HORIZON_NONE, late_mask

    horizons = design.evaluation.horizons
    out = np.zeros(len(flags), dtype=np.int64)
    late = frozen = prev = 0
    for k, f in enumerate(np.asarray(flags, dtype=np.int64)):
        f = int(f)
        frozen += 1 if prev and frozen < HORIZON_NONE else 0
        late |= f & ~prev & late_mask(horizons, frozen)
        out[k] = late
        prev = f
    return out


def escalation_summary(design: FdiDesign, t: np.ndarray, flags: np.ndarray,
                       cls: np.ndarray) -> dict:
    """When the decision turned ``unexplained``: the class isolated before (if any) and
    the flags that contradicted it (those rising at the escalation that no fault of that
    class, or no declared fault, explains)."""
    ev = design.evaluation
    hit = np.flatnonzero(cls == ev.unexplained)
    if not hit.size:
        return {"unexplained": None}
    k = int(hit[0])
    before = int(cls[k - 1]) if k else 0
    new = int(flags[k]) & ~(int(flags[k - 1]) if k else 0) & ev.class_flags
    if before:
        new &= ~ev.class_unions[before]
    return {"unexplained": {
        "t": float(t[k]), "contradicts": ev.classes[before],
        "t_contradicted": float(t[int(np.flatnonzero(cls == before)[0])]) if before else None,
        "contradicting_flags": [n for i, n in enumerate(ev.residuals) if new >> i & 1]}}


def fault_names(design: FdiDesign, mask: int) -> list:
    """Names of the declared faults whose bits are set in a consistent-fault mask."""
    return [n for k, n in enumerate(design.evaluation.fault_names) if mask >> k & 1]


def fault_set_text(names) -> str:
    """The consistent faults in words: ``"leak_p or blockage_p"``."""
    names = list(names)
    return "none" if not names else " or ".join(names)


def _consistent_masks(design: FdiDesign, out: dict, flags: np.ndarray) -> np.ndarray:
    """The backend's consistent-fault mask per sample (recomputed from the flags for a
    runner that does not output it)."""
    if "faults" in out:
        return np.asarray(out["faults"], dtype=np.int64)
    ev = design.evaluation
    return np.array([ev.consistent_faults(int(f)) for f in flags], dtype=np.int64)


def consistent_faults_summary(design: FdiDesign, consistent: np.ndarray) -> dict:
    """The faults consistent with the flags at the end of the run, and the last non-empty
    set (when later flags contradict every single fault, e.g. a second fault or a late
    consequence outside the signature, the last set that explained all flags)."""
    final = int(consistent[-1]) if len(consistent) else 0
    nonzero = np.flatnonzero(consistent)
    last = int(consistent[nonzero[-1]]) if nonzero.size else 0
    since = None
    if nonzero.size:
        j = int(nonzero[-1])
        other = np.flatnonzero(consistent[:j + 1] != last)
        since = int(other[-1]) + 1 if other.size else 0
    return {"consistent_faults": fault_names(design, final),
            "last_consistent_faults": fault_names(design, last),
            "fault_set": fault_set_text(fault_names(design, final or last)),
            "fault_set_sample": since}


def detect_log(design: FdiDesign, path: str | Path, backend: str = "auto") -> tuple[dict, dict]:
    """Read a log, run the FDI core over it, return ``(summary, raw outputs)``."""
    summary, out, _ = run_log(design, path, backend)
    return summary, out


def run_log(design: FdiDesign, path: str | Path, backend: str = "auto") -> tuple:
    """:func:`detect_log` with the log read: ``(summary, raw outputs, log)`` (the log as
    :func:`fdigen.sim.log.read_log` returns it, gaps as ``detect`` reads them)."""
    from fdigen.sim.log import read_log

    # a logger's few dropped samples interpolated, a longer outage run as it is: the
    # core holds its prediction and raises that sensor's validity flag (nf_<y>)
    log = read_log(path, design.model, sample_time=design.config.sample_time,
                   missing="keep")
    runner = fdi_runner(design, backend)
    outages = logger_outages(log.u)
    out = _run_between(runner, log.u, log.y, outages)
    summary = summarise_run(design, log.t, out, str(path))
    summary["backend"] = type(runner).__name__
    summary["missing"] = dict(log.missing)
    summary["outages"] = [[float(log.t[a]), float(log.t[b - 1])] for a, b in outages]
    return summary, out, log


def logger_outages(u: np.ndarray) -> list[tuple[int, int]]:
    """Sample ranges ``[a, b)`` where a command is missing (after the short gaps were
    interpolated): the logger's outage, not a fault. A user's fan log lost every column
    for 2 s; the core ran it as dead sensors and ended ``unexplained``, safety_stop."""
    lost = np.any(np.isnan(np.asarray(u, dtype=float).reshape(len(u), -1)), axis=1)
    edges = np.flatnonzero(np.diff(np.r_[0, lost.astype(np.int8), 0]))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def _run_between(runner, u, y, outages) -> dict:
    """The core over the log, started afresh after each outage (the plant was not
    observed, so nothing carries over); the outage's samples get no flag, no class and
    no action (residuals NaN)."""
    if not outages:
        return runner.run(u, y)
    K = len(u)
    bounds, start = [], 0
    for a, b in outages:
        if a > start:
            bounds.append((start, a))
        start = b
    if start < K:
        bounds.append((start, K))
    parts = [(a, b, runner.run(u[a:b], y[a:b])) for a, b in bounds if b - a >= 2]
    if not parts:
        from fdigen.errors import LogError

        raise LogError("the log holds no two consecutive samples with every command "
                       "logged: nothing to diagnose")
    out = {}
    for key, value in parts[0][2].items():
        value = np.asarray(value)
        full = np.full((K,) + value.shape[1:],
                       np.nan if np.issubdtype(value.dtype, np.floating) else 0,
                       dtype=value.dtype)
        for a, b, o in parts:
            full[a:b] = np.asarray(o[key])
        out[key] = full
    return out
