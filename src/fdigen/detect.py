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
    for i, name in enumerate(ev.residuals):
        on = np.flatnonzero((flags >> i) & 1)
        if on.size:
            raised.append({"residual": name, "t_raised": float(t[on[0]])})
    raised.sort(key=lambda f: (f["t_raised"], f["residual"]))
    cls = np.asarray(out["fault_class"])
    iso = np.flatnonzero(cls > 0)
    consistent = _consistent_masks(design, out, flags)
    if iso.size:
        k = int(iso[0])
        diagnosis = {"fault": ev.classes[int(cls[k])], "t_isolated": float(t[k]),
                     "action": ev.actions[int(cls[k])],
                     "candidates": fault_names(design, int(consistent[k]))}
    else:
        diagnosis = {"fault": "none", "t_isolated": None, "action": "none",
                     "candidates": []}
    diagnosis.update(consistent_faults_summary(design, consistent))
    k_set = diagnosis.pop("fault_set_sample")
    diagnosis["t_fault_set"] = None if k_set is None else float(t[k_set])
    if not iso.size and raised:
        # ambiguous: the faults still consistent with the flags (never an empty list
        # while one is; see docs/isolation.md)
        diagnosis["candidates"] = diagnosis["consistent_faults"] or \
            diagnosis["last_consistent_faults"]
    dt = float(f"{np.median(np.diff(t)):.12g}") if len(t) > 1 else float("nan")
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
    from fdigen.sim.log import read_log

    log = read_log(path, design.model, sample_time=design.config.sample_time)
    runner = fdi_runner(design, backend)
    out = runner.run(log.u, log.y)
    summary = summarise_run(design, log.t, out, str(path))
    summary["backend"] = type(runner).__name__
    return summary, out
