"""The paper's experiments (Table 2, sections 5.1-5.3), reproduced with fdigen's simulator.

Each experiment injects one of the model's faults into the closed loop at the paper's fault
time, runs the FDI core over the simulated log and records which flags rose and when, the
isolated class and its action, the detection delay (first flag minus fault time), the
isolation delay and the delay until the last flag of the fault's signature rose (what the
paper's "time taken to detect" measures: in five of its six rows it equals the time of
the last raised flag minus the fault time). The flags are checked against the derived
signature table. The reference rig's ``fdi_*`` logs are run through
:func:`fdigen.detect.detect_log` and compared with the ground truth beside them.

``fdigen experiments -o EXPERIMENTS.md`` writes the result through the template
``templates/docs/experiments.md.j2``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from fdigen.design.fdi_design import FdiDesign
from fdigen.errors import FdigenError
from fdigen.report import markdown_code, markdown_text
from fdigen.resources import SOURCE_ROOT

#: Where the reference rig's logs are looked for when no folder is given (and
#: ``FDIGEN_RIG_LOGS`` is not set): ``../shared/rig/logs`` beside the source checkout, or
#: beside the current folder for an installed fdigen.
DEFAULT_RIG_LOGS = (SOURCE_ROOT.parent if SOURCE_ROOT is not None else Path("..")) \
    / "shared" / "rig" / "logs"

#: The paper's action names (Table 2) for fdigen's actions.
PAPER_ACTIONS = {"accommodate": "Fault accommodated", "none": "No action",
                 "safety_stop": "Safety mode activated"}

#: Fault kinds of the rig logs' ground truth -> the model's fault class.
TRUTH_CLASSES = {"actuator_loss": "pneumatic_or_actuator", "leak": "pneumatic_or_actuator",
                 "blockage": "pneumatic_or_actuator",
                 "position_sensor_loss": "position_sensor",
                 "pressure_n_drift": "pressure_sensor_n",
                 "pressure_p_loss": "pressure_sensor_p"}


class ExperimentError(FdigenError):
    """The experiments cannot be run (a model without the paper's faults)."""


@dataclass(frozen=True)
class PaperRow:
    """One experiment of the paper's Table 2, re-aligned with sections 5.1-5.3.

    ``flags`` maps the residual to the time its flag rose [s]; ``delay`` is the column
    "time taken to detect fault" [s].
    """

    fault_time: float
    flags: dict
    delay: float
    action: str
    fault_type: str


@dataclass(frozen=True)
class Experiment:
    """A fault experiment: a model fault injected at ``t0`` (a ramp if ``ramp``)."""

    key: str
    title: str
    fault: str | None
    size: float
    t0: float
    ramp: bool = False
    note: str = ""
    paper: PaperRow | None = None


#: The six experiments of Table 2, then a healthy run of the same length as the longest.
PAPER_EXPERIMENTS = (
    Experiment("position_sensor_loss", "Position sensor fault (signal loss)",
               "position_sensor", -1.0, 42.69,
               note="multiplicative fault -1: the primary sensor x3 reads 0",
               paper=PaperRow(42.69, {"R1": 42.72, "R4": 42.7, "w3": 42.705}, 0.3,
                              "Fault accommodated", "Sensor")),
    Experiment("pressure_n_drift", "Pressure sensor (n) drift", "pressure_sensor_n",
               2.0e4, 20.0, ramp=True,
               note="additive ramp of 20 kPa/s (the paper does not give its rate; the rig "
                    "log uses the same)",
               paper=PaperRow(20.0, {"R3": 22.47, "R5": 22.2}, 2.47, "No action", "Sensor")),
    Experiment("blockage_p", "Air blockage (line p)", "blockage_p", 0.95, 35.0,
               note="blockage_p = 0.95: 5 % of the valve flow reaches chamber p",
               paper=PaperRow(35.0, {"R1": 41.84, "R2": 41.8, "R3": 41.8, "R4": 39.39,
                                     "R5": 38.64}, 6.84, "Safety mode activated",
                              "Pneumatic")),
    Experiment("leak_p", "Air leak (line p)", "leak_p", 3e-10, 18.6,
               note="leak to atmosphere, 3e-10 kg/(s Pa)",
               paper=PaperRow(18.6, {"R1": 23.98, "R2": 18.67, "R3": 18.5, "R4": 18.92,
                                     "R5": 18.78}, 5.38, "Safety mode activated",
                              "Pneumatic")),
    Experiment("pressure_p_loss", "Pressure sensor (p) signal loss", "pressure_sensor_p",
               -3.3e5, 32.95,
               note="emulated: the model's pressure_sensor_p fault is additive, so the loss "
                    "is a step of -3.3e5 Pa (the sensor then reads Pp - 330 kPa, near 0)",
               paper=PaperRow(32.95, {"R2": 33.2, "R5": 33.2}, 0.25, "No action", "Sensor")),
    Experiment("actuator_loss", "Actuator fault (control signal loss)", "valve", -1.0, 20.0,
               note="multiplicative fault -1 on the valve voltage: no flow",
               paper=PaperRow(20.0, {"R1": 21.55, "R2": 21.62, "R3": 21.61, "R4": 20.65,
                                     "R5": 20.96}, 1.62, "Safety mode activated",
                              "Pneumatic")),
    Experiment("healthy", "No fault (false-alarm check)", None, 0.0, 42.69,
               note="the longest run's length, no fault: no flag may rise"),
)


@dataclass(frozen=True)
class Outcome:
    """What the FDI decided on one run with a known fault.

    Times are in seconds on the log's clock; delays are relative to ``t0`` and ``None``
    when the event did not happen.
    """

    name: str
    t0: float | None
    expected_class: str
    flags: tuple                      # ((residual, t_raised), ...) in order of rising
    fault_class: str
    action: str
    t_isolated: float | None
    detection_delay: float | None
    isolation_delay: float | None
    signature: tuple = ()             # derived signature of the injected fault
    missing: tuple = ()               # signature residuals that never rose
    outside: tuple = ()               # ((residual, t_raised), ...) not in the signature
    signature_delay: float | None = None
    candidates: tuple = ()
    signature_of: str = ""            # the fault (or class) the signature is that of
    extra: dict = field(default_factory=dict)

    @property
    def correct(self) -> bool:
        return self.fault_class == self.expected_class


def _delay(t, t0):
    return None if t is None or t0 is None else t - t0


def outcome(design: FdiDesign, summary: dict, name: str, signature, expected_class: str,
            t0: float | None, dt: float) -> Outcome:
    """Compare a run's decision (:func:`fdigen.detect.summarise_run`) with its fault.

    Parameters
    ----------
    design : FdiDesign
    summary : dict
        The run's decision.
    name : str
    signature : set of str or None
        Residuals the injected fault should raise (Table 1, derived); ``None``: unknown.
    expected_class : str
        The class the injected fault belongs to (``"none"`` for a healthy run).
    t0 : float or None
        Fault time [s]; ``None`` for a healthy run.
    dt : float
        Sample time [s]: times are rounded to it.
    """
    digits = max(0, int(round(-np.log10(dt)))) if dt > 0 else 6
    flags = tuple((f["residual"], round(f["t_raised"], digits)) for f in summary["flags"])
    d = summary["diagnosis"]
    t_iso = None if d["t_isolated"] is None else round(d["t_isolated"], digits)
    order = design.evaluation.residuals
    raised = dict(flags)
    sig = set(signature or ())
    missing = tuple(r for r in order if r in sig and r not in raised)
    outside = tuple((r, t) for r, t in flags if signature is not None and r not in sig)
    in_sig = [t for r, t in flags if r in sig]
    sig_delay = _delay(max(in_sig), t0) if in_sig and not missing else None
    rnd = (lambda v: None if v is None else round(v, digits))
    return Outcome(name, t0, expected_class, flags, d["fault"], d["action"], t_iso,
                   rnd(_delay(flags[0][1] if flags else None, t0)),
                   rnd(_delay(t_iso, t0)), tuple(r for r in order if r in sig),
                   missing, outside, rnd(sig_delay), tuple(d["candidates"]))


def run_experiment(design: FdiDesign, experiment: Experiment, runner, *, after: float = 15.0,
                   t0: float | None = None, seed: int = 0) -> Outcome:
    """Simulate one experiment in closed loop and run the FDI core over it.

    Parameters
    ----------
    design : FdiDesign
    experiment : Experiment
    runner
        An FDI runner (:func:`fdigen.detect.fdi_runner`), reused across experiments.
    after : float
        Seconds simulated after the fault time.
    t0 : float, optional
        Fault time [s]; default the paper's.
    seed : int
        Seed of the sensor noise.
    """
    from fdigen.detect import summarise_run
    from fdigen.sim.plant import FaultEvent, simulate

    model = design.model
    t0 = experiment.t0 if t0 is None else float(t0)
    events = []
    expected = "none"
    if experiment.fault is not None:
        events = [FaultEvent(experiment.fault, t0, experiment.size, experiment.ramp)]
        expected = model.fault(experiment.fault).fault_class
    sim = simulate(model, t0 + after, faults=events, seed=seed,
                   dt=design.config.sample_time)
    out = runner.run(sim.u, sim.y)
    summary = summarise_run(design, sim.t, out, experiment.key)
    signature = design.signature_table[experiment.fault] if experiment.fault else set()
    result = outcome(design, summary, experiment.key, signature, expected,
                     t0 if experiment.fault else None, design.config.sample_time)
    return replace(result, signature_of=experiment.fault or "none",
                   extra={"backend": type(runner).__name__})


def check_model(design: FdiDesign, experiments=PAPER_EXPERIMENTS) -> None:
    """Raise :class:`ExperimentError` unless the model has every experiment's fault."""
    names = {f.name for f in design.model.faults}
    for e in experiments:
        if e.fault is not None and e.fault not in names:
            raise ExperimentError(
                f"model '{design.model.name}' has no fault '{e.fault}' (experiment {e.key}); "
                "the paper's experiments are defined for the pneumatic_cylinder model")


def run_experiments(design: FdiDesign, backend: str = "auto", *, after: float = 15.0,
                    seed: int = 0, experiments=PAPER_EXPERIMENTS) -> list[Outcome]:
    """Run every experiment with one FDI runner; see :func:`run_experiment`."""
    from fdigen.detect import fdi_runner

    check_model(design, experiments)
    runner = fdi_runner(design, backend)
    return [run_experiment(design, e, runner, after=after, seed=seed) for e in experiments]


#: Largest ground-truth JSON read beside a rig log [bytes].
TRUTH_LIMIT = 1 << 20


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) \
        and bool(np.isfinite(value))


def _json_type(value) -> str:
    return {dict: "an object", list: "an array", str: "a string", bool: "a boolean",
            type(None): "null"}.get(type(value), "a number")


def check_truth(doc, path) -> dict:
    """``doc`` (a parsed ground truth) if it has the expected shape, else
    :class:`ExperimentError` naming ``path`` and the field: an object whose optional
    ``truth`` is an object whose optional ``faults`` is a list of objects, each with a
    string ``kind`` and a finite number ``t0`` [s]."""
    def bad(what):
        return ExperimentError(f"{path}: malformed ground truth: {what}")

    if not isinstance(doc, dict):
        raise bad(f"not a JSON object but {_json_type(doc)}")
    truth = doc.get("truth", {})
    if not isinstance(truth, dict):
        raise bad(f"'truth' is not an object but {_json_type(truth)}")
    faults = truth.get("faults", [])
    if not isinstance(faults, list):
        raise bad(f"'truth.faults' is not a list but {_json_type(faults)}")
    for i, fault in enumerate(faults):
        where = f"'truth.faults[{i}]'"
        if not isinstance(fault, dict):
            raise bad(f"{where} is not an object but {_json_type(fault)}")
        if not isinstance(fault.get("kind"), str):
            raise bad(f"{where} has no string 'kind'")
        if not _is_number(fault.get("t0")):
            raise bad(f"{where} has no numeric 't0' (a finite number of seconds)")
    return doc


def read_truth(log_path: str | Path) -> dict:
    """The ground truth JSON beside a rig log (``{}`` if there is none), checked by
    :func:`check_truth`.

    Raises
    ------
    ExperimentError
        If it cannot be read (not a regular file, larger than :data:`TRUTH_LIMIT`), is no
        JSON (or nested too deeply) or has not the shape of a ground truth.
    """
    from fdigen.files.bounded import read_bytes

    path = Path(log_path).with_suffix(".json")
    if not path.is_file():
        return {}
    data = read_bytes(path, TRUTH_LIMIT, what="ground truth", error=ExperimentError)
    try:
        doc = json.loads(data.decode("utf-8"))
    except RecursionError:
        raise ExperimentError(f"{path}: unreadable ground truth (JSON nested too "
                              "deeply)") from None
    except (UnicodeDecodeError, ValueError) as exc:
        raise ExperimentError(f"{path}: unreadable ground truth ({exc})") from None
    return check_truth(doc, path)


def truth_text(fault: dict | None) -> str:
    """``kind at t0 s (parameters)`` for a ground-truth fault, ``healthy`` for none."""
    if not fault:
        return "healthy"
    params = ", ".join(f"{k} {v:g}" if isinstance(v, (int, float)) else f"{k} {v}"
                       for k, v in fault.items() if k not in ("kind", "t0"))
    return f"{fault['kind']} at {fault['t0']:g} s" + (f" ({params})" if params else "")


def expected_class(truth: dict | None) -> tuple[str, dict | None]:
    """The class a ground truth's faults belong to, and its single fault (or ``None``).

    ``truth`` is the JSON beside a rig log (``{}``: there is none, the class is unknown).
    """
    if not truth:
        return "unknown (no ground truth)", None
    faults = truth.get("truth", {}).get("faults", [])
    if not faults:
        return "none", None
    if len(faults) > 1:
        return "several faults", None
    kind = str(faults[0].get("kind"))
    return TRUTH_CLASSES.get(kind, f"unknown kind {kind}"), faults[0]


def rig_log_outcome(design: FdiDesign, path: str | Path, backend: str = "auto") -> Outcome:
    """Run :func:`fdigen.detect.detect_log` on a rig log; compare with its ground truth.

    The rig's faults are not the model's faults by name, so the flags are checked against
    the signature of the expected class (every residual some fault of the class raises);
    a fault of the class need not raise all of it, so nothing is reported missing.
    """
    from fdigen.detect import detect_log
    from fdigen.report import class_signature

    summary, _ = detect_log(design, path, backend)
    expected, fault = expected_class(read_truth(path))
    try:
        t0 = None if fault is None else float(fault["t0"])
    except (KeyError, TypeError, ValueError):
        raise ExperimentError(f"{Path(path).with_suffix('.json')}: fault without a "
                              "numeric 't0'") from None
    classes = set(design.evaluation.classes)
    signature = (class_signature(design, expected) if expected in classes - {"none"}
                 else set() if expected == "none" else None)
    result = outcome(design, summary, Path(path).name, signature, expected, t0,
                     summary["sample_time"])
    return replace(result, missing=(), signature_delay=None, signature_of=expected,
                   extra={"truth": truth_text(fault) if fault or expected == "none"
                          else expected})


def rig_log_outcomes(design: FdiDesign, folder: str | Path, backend: str = "auto",
                     pattern: str = "fdi_*.csv") -> list[Outcome]:
    """:func:`rig_log_outcome` for every log of ``folder`` matching ``pattern``, sorted."""
    return [rig_log_outcome(design, p, backend) for p in sorted(Path(folder).glob(pattern))]


def default_rig_logs() -> Path | None:
    """``$FDIGEN_RIG_LOGS``, else the reference rig's logs beside the repository, if any."""
    folder = Path(os.environ.get("FDIGEN_RIG_LOGS", DEFAULT_RIG_LOGS))
    return folder if folder.is_dir() else None


# -- the document ----------------------------------------------------------------------
def _t(value, fmt=".3f") -> str:
    return "-" if value is None else format(value, fmt)


def _flag_list(flags) -> str:
    return ", ".join(f"{r} {t:.3f}" for r, t in flags) or "none"


def _remarks(outcomes, after: float | None) -> list[str]:
    """Facts worth a reader's attention: wrong or no isolation, missing/outside flags."""
    notes = []
    for o in outcomes:
        if not o.correct:
            what = "not isolated" if o.fault_class == "none" else f"isolated as {o.fault_class}"
            notes.append(f"{o.name}: {what}, expected {o.expected_class}.")
        if o.missing:
            horizon = f"within {after:g} s of the fault" if after else "in the log"
            notes.append(f"{o.name}: signature residuals that did not rise {horizon}: "
                         f"{', '.join(o.missing)}.")
        if o.expected_class == "none" and o.flags:
            notes.append(f"{o.name}: false alarm(s): {_flag_list(o.flags)}.")
        elif o.outside:
            when = [f"{r} {t:.3f}" + (" (before isolation)" if o.t_isolated is None
                                      or t < o.t_isolated else "") for r, t in o.outside]
            notes.append(f"{o.name}: flags outside the signature of {o.signature_of}: "
                         f"{', '.join(when)}; isolated at {_t(o.t_isolated)} s.")
    return notes


def experiment_rows(experiments, outcomes) -> list[dict]:
    """Rows of the side-by-side table and of the signature check, as display strings."""
    rows = []
    for e, o in zip(experiments, outcomes):
        p = e.paper
        rows.append({
            "key": e.key, "title": e.title, "fault": e.fault or "-", "note": e.note,
            "size": "-" if e.fault is None else (f"{e.size:g}/s" if e.ramp else f"{e.size:g}"),
            "t0": _t(o.t0, "g") if e.fault else "-", "flags": _flag_list(o.flags),
            "paper_flags": "-" if p is None else _flag_list(sorted(p.flags.items(),
                                                                   key=lambda f: f[1])),
            "fault_class": o.fault_class, "expected_class": o.expected_class,
            "action": o.action, "paper_action": "-" if p is None else p.action,
            "paper_type": "-" if p is None else p.fault_type,
            "detection": _t(o.detection_delay), "isolation": _t(o.isolation_delay),
            "signature_delay": _t(o.signature_delay), "paper_delay": "-" if p is None
            else f"{p.delay:g}", "paper_t0": "-" if p is None else f"{p.fault_time:g}",
            "signature": ", ".join(o.signature) or "-",
            "raised": ", ".join(r for r, _ in o.flags) or "none",
            "missing": ", ".join(o.missing) or "-",
            "outside": ", ".join(f"{r} {t:.3f}" for r, t in o.outside) or "-",
            "correct": "yes" if o.correct else "no",
        })
    return rows


def rig_rows(outcomes) -> list[dict]:
    """Rows of the rig-log table, as display strings."""
    return [{"log": o.name, "truth": o.extra.get("truth", "-"), "expected": o.expected_class,
             "fault_class": o.fault_class, "action": o.action,
             "t_isolated": _t(o.t_isolated), "flags": _flag_list(o.flags),
             "detection": _t(o.detection_delay), "isolation": _t(o.isolation_delay),
             "outside": ", ".join(f"{r} {t:.3f}" for r, t in o.outside) or "-",
             "correct": "yes" if o.correct else "no"} for o in outcomes]


def experiments_document(design: FdiDesign, outcomes, rig_outcomes=None, *, after: float,
                         seed: int, backend: str | None = None,
                         experiments=PAPER_EXPERIMENTS, rig_folder: str = "") -> str:
    """The markdown document (``templates/docs/experiments.md.j2``).

    Parameters
    ----------
    design : FdiDesign
    outcomes : list of Outcome
        Of :func:`run_experiments`, in the order of ``experiments``.
    rig_outcomes : list of Outcome, optional
        Of :func:`rig_log_outcomes`; ``None``: the rig section says the logs were not found.
    after, seed :
        The settings the experiments ran with (written into the text).
    backend : str, optional
        The FDI runner's name; default: the one the outcomes record.
    rig_folder : str
        The rig logs' folder as shown in the text (no absolute path: the document must not
        depend on where it was generated).

    Every string of the template's context is Markdown-escaped here
    (:func:`fdigen.report.markdown_text`): log file names, a ground truth's text, the
    folder come from inputs and are shown as literal text (no HTML, link, table cell or
    code span of theirs); the names in inline code go through
    :func:`fdigen.report.markdown_code`.
    """
    if backend is None:
        backend = outcomes[0].extra.get("backend", "?") if outcomes else "?"
    from fdigen import __version__
    from fdigen.backends.render import environment
    from fdigen.model.model_file import model_hash

    model = design.model
    ev = design.evaluation
    context = dict(
        version=__version__, model_name=model.name, model_hash=model_hash(model)[:16],
        backend=backend, after=f"{after:g}", seed=seed,
        sample_time=f"{design.config.sample_time:g}", window=ev.window, confirm=ev.confirm,
        thresholds=[(r, f"{j:g}") for r, j in zip(ev.residuals, ev.thresholds)],
        rows=experiment_rows(experiments, outcomes),
        remarks=_remarks(outcomes, after), rig_remarks=_remarks(rig_outcomes or [], None),
        rig=None if rig_outcomes is None else rig_rows(rig_outcomes),
        rig_correct=sum(o.correct for o in rig_outcomes or []),
        sim_correct=sum(o.correct for o in outcomes))
    context = _markdown_context(context)
    context.update(model_code=markdown_code(model.name),
                   rig_logs=markdown_code(f"{rig_folder}fdi_*.csv"))
    return environment().get_template("docs/experiments.md.j2").render(**context)


def _markdown_context(value):
    """``value`` with every string in it (in dicts, lists, tuples) Markdown-escaped."""
    if isinstance(value, str):
        return markdown_text(value)
    if isinstance(value, dict):
        return {k: _markdown_context(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(_markdown_context(v) for v in value)
    return value
