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
    if iso.size:
        k = int(iso[0])
        fault = ev.classes[int(cls[k])]
        mask = int(flags[k])
        candidates = sorted(f for f, s in design.signature_table.items()
                            if mask & ~sum(1 << ev.residuals.index(r) for r in s) == 0)
        diagnosis = {"fault": fault, "t_isolated": float(t[k]),
                     "action": ev.actions[int(cls[k])], "candidates": candidates}
    else:
        diagnosis = {"fault": "none", "t_isolated": None, "action": "none", "candidates": []}
    dt = float(f"{np.median(np.diff(t)):.12g}") if len(t) > 1 else float("nan")
    return {"log": log, "sample_time": dt, "samples": int(len(t)), "flags": raised,
            "diagnosis": diagnosis, "detected": bool(raised)}


def detect_log(design: FdiDesign, path: str | Path, backend: str = "auto") -> tuple[dict, dict]:
    """Read a log, run the FDI core over it, return ``(summary, raw outputs)``."""
    from fdigen.sim.log import read_log

    log = read_log(path, design.model, sample_time=design.config.sample_time)
    runner = fdi_runner(design, backend)
    out = runner.run(log.u, log.y)
    summary = summarise_run(design, log.t, out, str(path))
    summary["backend"] = type(runner).__name__
    return summary, out
