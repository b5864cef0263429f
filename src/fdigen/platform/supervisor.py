"""The supervisory logic of the platform (Python reference of the generated C).

Each leg runs the single-cylinder FDI (:mod:`fdigen.design.fdi_design`), which latches an
isolated fault class and the class's action from the model file's ``[fdi.actions]``
(for the cylinder: position sensor -> ``accommodate``, pressure sensors -> ``none``,
pneumatic or actuator -> ``safety_stop``). The supervisor combines the six decisions:

* **Leg decision** ``d_i``: the leg's isolated class, latched (0 = none); its action
  ``a_i = action(d_i)``. A sensor fault is handled on its leg: the leg's FDI switches the
  position used by its controller to the voter's output (``accommodate``), or the sensor
  is simply not used by the loop (``none``); the platform keeps moving.
* **Platform action** ``A = max_i a_i`` (actions are ordered ``none < accommodate <
  safety_stop``), and the **faulty leg**: the first leg (in time, then by index) whose
  decision reached the most severe level ``lambda_i = 1 + a_i`` (0 without a decision).
* **Safety sequence**: the first sample ``k_s`` with ``A = safety_stop`` freezes the leg
  demands ``x_0 = clip(xref[k_s], 0, L)`` (a NaN or infinite demand is refused: its leg
  keeps its demand in force; a start that is not finite is the rest position)
  and, from then on, drives every leg to its rest
  position ``x_rest`` (the inverse kinematics of the rest pose) with a quintic
  time-scaling in leg space over ``T`` seconds:

  .. math::

      \\sigma_n = \\min(n\\, \\Delta t / T, 1),\\quad
      s(\\sigma) = \\sigma^3 (10 + \\sigma(-15 + 6\\sigma)),\\quad
      x_{ref,i}[k_s + n] = x_{0,i} + (x_{rest,i} - x_{0,i})\\, s(\\sigma_n)

  Every leg moves monotonically between two points of its stroke, so the path stays in
  ``[0, L]``; velocity and acceleration are zero at both ends (at most ``15/8 |x_rest -
  x_0| / T``). :func:`check_safety_path` samples it and also checks that a platform pose
  exists along it (forward kinematics).

Timing: at sample ``k`` the controller uses ``xref[k]``; the FDI bank and the supervisor
then run on ``(u[k], y[k])``; the demand they return is ``xref[k+1]`` while the safety
sequence runs (``n = 1`` at the trigger sample), the motion demand otherwise. The
generated ``<model>_platform_step`` (:mod:`fdigen.platform.codegen`) implements exactly
this, and the tests compare the two sample for sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fdigen.design.config import ACTIONS
from fdigen.design.fdi_design import FdiDesign
from fdigen.errors import FdigenError
from fdigen.platform.demands import quintic
from fdigen.platform.geometry import NLEGS, PlatformGeometry

#: Seconds of the safety sequence by default (the platform's longest leg travel, 160 mm,
#: at a peak speed of 15/8 * 0.16 / 3 = 0.1 m/s).
DEFAULT_SAFETY_DURATION = 3.0

SAFETY = ACTIONS.index("safety_stop")
ACCOMMODATE = ACTIONS.index("accommodate")


#: Samples the safety sequence may last at most: the generated C counts them in an int32
#: (``state->n`` saturates at ``INT32_MAX``), and a sequence that has not ended by then would
#: stop short of the rest pose for good.
MAX_SAFETY_SAMPLES = 2**31 - 1


def check_safety_duration(duration, dt: float, float_type: str = "double") -> float:
    """``T`` of the safety sequence, checked: finite, at least one sample time ``dt`` (a
    shorter one is not a sequence but a jump of every leg to its rest position), at most
    :data:`MAX_SAFETY_SAMPLES` samples, and a normal number of ``float_type`` (the real
    type of the generated C: ``1e-300`` printed as ``0.0f`` made the C's own defaults fail
    ``_init``; ``1e-45`` was a subnormal float).

    Returns
    -------
    float

    Raises
    ------
    FdigenError
        Naming the value and the range (the command line names its option).
    """
    try:
        T = float(duration)
    except (TypeError, ValueError):
        raise FdigenError(f"safety duration {duration!r} is not a number") from None
    dt = float(dt)
    longest = MAX_SAFETY_SAMPLES * dt
    text = f"{T:g} s"
    if not np.isfinite(T) or not T > 0:
        raise FdigenError(f"safety duration {text}: must be a finite number of seconds > 0")
    if T < dt:
        raise FdigenError(f"safety duration {text} is shorter than one sample ({dt:g} s): "
                          "every leg would jump to its rest position in one sample; "
                          f"between {dt:g} and {longest:.6g} s")
    if T > longest:
        raise FdigenError(f"safety duration {text} is longer than {MAX_SAFETY_SAMPLES} "
                          f"samples ({longest:.6g} s): the generated C's sample counter "
                          "saturates before the rest pose; between "
                          f"{dt:g} and {longest:.6g} s")
    if float_type == "float":
        f32 = np.finfo(np.float32)
        if not float(f32.tiny) <= T <= float(f32.max):
            raise FdigenError(f"safety duration {text} is not a normal single-precision "
                              f"number (--float-type float: {float(f32.tiny):.3g} to "
                              f"{float(f32.max):.3g})")
    return T


def safe_start(demand, rest, stroke: float) -> np.ndarray:
    """The safety sequence's start: the demands clipped to ``[0, stroke]``, a NaN or
    infinite one replaced by its leg's rest position (as the generated C; a NaN went
    through the clip, and that leg was commanded NaN for the rest of the run)."""
    d = np.asarray(demand, dtype=float)
    return np.where(np.isfinite(d), np.clip(d, 0.0, stroke), np.asarray(rest, dtype=float))


def safety_path(start, rest, duration: float, dt: float, samples: int | None = None):
    """The safety sequence's leg demands ``x[n]``, ``n = 0..samples-1`` (``x[0] = start``).

    Parameters
    ----------
    start, rest : array_like, shape (6,)
        Piston positions at the trigger and at rest [m].
    duration, dt : float
        ``T`` and the sample time [s].
    samples : int, optional
        Default: until the rest pose is reached, ``ceil(T/dt) + 1``.

    Returns
    -------
    numpy.ndarray, shape (samples, 6)
    """
    if samples is None:
        samples = int(np.ceil(duration / dt)) + 1
    start, rest = np.asarray(start, dtype=float), np.asarray(rest, dtype=float)
    n = np.arange(samples, dtype=float)
    s = quintic(np.minimum(n * dt / duration, 1.0))
    return start + (rest - start) * s[:, None]


def check_safety_path(geometry: PlatformGeometry, start, duration: float, dt: float, *,
                      forward: bool = True, every: int = 50) -> dict:
    """Sample the safety sequence from ``start`` and check it against every leg's stroke.

    Parameters
    ----------
    geometry : PlatformGeometry
    start : array_like, shape (6,)
        Leg demands at the trigger [m] (clipped to the stroke, as the supervisor does).
    duration, dt : float
    forward : bool
        Also solve the forward kinematics every ``every`` samples (a pose exists along
        the path, continued from the previous one).

    Returns
    -------
    dict
        ``min_mm``, ``max_mm`` per leg, ``max_speed`` [m/s], ``poses`` checked, and
        ``max_pose_step`` (largest change between checked poses).

    Raises
    ------
    ReachabilityError
        If a sample leaves a leg's stroke (names the leg and by how much).
    FdigenError
        If no pose matches the leg lengths somewhere along the path.
    """
    x0 = safe_start(start, geometry.rest_positions, geometry.stroke)
    path = safety_path(x0, geometry.rest_positions, duration, dt)
    geometry.check_positions(path, t=np.arange(len(path)) * dt, what="safety sequence")
    info = {"samples": len(path), "min_mm": (path.min(axis=0) * 1e3).tolist(),
            "max_mm": (path.max(axis=0) * 1e3).tolist(),
            "max_speed": float(np.max(np.abs(np.diff(path, axis=0))) / dt)}
    if forward:
        q = None
        poses = []
        for k in list(range(0, len(path), every)) + [len(path) - 1]:
            q = geometry.forward_kinematics(geometry.positions_to_lengths(path[k]), q)
            poses.append(q)
        poses = np.array(poses)
        info["poses"] = len(poses)
        info["max_pose_step"] = float(np.max(np.abs(np.diff(poses, axis=0))))
        info["end_pose_error"] = float(np.max(np.abs(poses[-1] - geometry.rest)))
    return info


@dataclass
class SupervisorStep:
    """The supervisor's outputs at one sample.

    Attributes
    ----------
    decision : numpy.ndarray of int, (6,)
        Latched isolated class per leg (index into the design's classes, 0 = none).
    leg_action : numpy.ndarray of int, (6,)
        Action code per leg (index into :data:`fdigen.design.config.ACTIONS`).
    action : int
        Platform action code ``max_i leg_action``.
    faulty_leg : int
        0..5, the leg behind the platform action, -1 none.
    safety : bool
        The safety sequence runs (latched).
    progress : float
        ``sigma`` of the safety sequence, 0..1.
    demand : numpy.ndarray, (6,)
        Leg demands: the safety trajectory's for the next sample while ``safety``, the
        motion demand given for this sample otherwise.
    """

    decision: np.ndarray
    leg_action: np.ndarray
    action: int
    faulty_leg: int
    safety: bool
    progress: float
    demand: np.ndarray


class Supervisor:
    """The supervisory state machine over the six legs' FDI decisions.

    Parameters
    ----------
    design : FdiDesign
        The single-leg design (its classes, actions and sample time).
    geometry : PlatformGeometry
        Gives the rest positions and the stroke.
    safety_duration : float
        ``T`` of the safety sequence [s].
    """

    def __init__(self, design: FdiDesign, geometry: PlatformGeometry,
                 safety_duration: float = DEFAULT_SAFETY_DURATION):
        self.design = design
        self.geometry = geometry
        self.classes = design.evaluation.classes
        self.codes = np.array(design.evaluation.action_codes, dtype=np.int64)
        self.dt = float(design.config.sample_time)
        self.duration = check_safety_duration(safety_duration, self.dt)
        self.rest = np.array(geometry.rest_positions, dtype=float)
        self.stroke = float(geometry.stroke)
        self.reset()

    def reset(self):
        """Back to normal operation, no decision."""
        self.decision = np.zeros(NLEGS, dtype=np.int64)
        self.level = 0
        self.faulty_leg = -1
        self.safety = False
        self.n = 0
        self.start = self.rest.copy()
        self.demand = self.rest.copy()
        self.trigger_sample = None
        self.k = 0

    def step(self, fault_class, demand) -> SupervisorStep:
        """One sample: the legs' isolated classes and the motion demands of this sample.

        Parameters
        ----------
        fault_class : array_like of int, (6,)
            Each leg FDI's ``fault_class`` output at this sample.
        demand : array_like, (6,)
            The leg demands applied at this sample (ignored once the safety sequence
            runs: it then generates its own). A NaN or infinite demand is refused as
            the generated C's ``set_demand`` refuses it: its leg keeps its demand in
            force (finite).

        Returns
        -------
        SupervisorStep
        """
        fc = np.asarray(fault_class, dtype=np.int64)
        new = (self.decision == 0) & (fc != 0)
        self.decision[new] = fc[new]
        leg_action = self.codes[self.decision]
        for i in range(NLEGS):
            level = 1 + int(leg_action[i]) if self.decision[i] else 0
            if level > self.level:
                self.level, self.faulty_leg = level, i
        if not self.safety:
            d = np.array(demand, dtype=float)
            # a NaN or infinite demand is refused, as the C's set_demand: its leg keeps
            # its demand in force
            self.demand = np.where(np.isfinite(d), d, self.demand)
            if self.level == 1 + SAFETY:
                self.safety = True
                self.start = safe_start(self.demand, self.rest, self.stroke)
                self.n = 0
                self.trigger_sample = self.k
        sigma = 0.0
        if self.safety:
            self.n += 1
            sigma = min(self.n * self.dt / self.duration, 1.0)
            s = sigma * sigma * sigma * (10.0 + sigma * (-15.0 + 6.0 * sigma))
            self.demand = self.start + (self.rest - self.start) * s
        self.k += 1
        return SupervisorStep(self.decision.copy(), leg_action,
                              max(self.level - 1, 0), self.faulty_leg, self.safety, sigma,
                              self.demand.copy())


class PlatformFdi:
    """Six single-leg FDIs and the :class:`Supervisor`: the Python reference of the bank.

    ``step(u, y, demand)`` has the interface of the generated C bank
    (:class:`fdigen.platform.codegen.PlatformCFdi`).

    Parameters
    ----------
    design : FdiDesign
    geometry : PlatformGeometry
    safety_duration : float
    backend : str
        Single-leg FDI of each leg, as :func:`fdigen.detect.fdi_runner` (needs ``step``).
    """

    def __init__(self, design: FdiDesign, geometry: PlatformGeometry,
                 safety_duration: float = DEFAULT_SAFETY_DURATION, backend: str = "auto"):
        from fdigen.detect import fdi_runner

        self.design = design
        self.legs = [fdi_runner(design, backend) for _ in range(NLEGS)]
        self.supervisor = Supervisor(design, geometry, safety_duration)
        aux = design.aux_names
        self.pfc_index = aux.index("position_for_control") if "position_for_control" in aux \
            else None
        self.reset()

    def reset(self):
        for leg in self.legs:
            leg.reset()
        self.supervisor.reset()

    def step(self, u, y, demand) -> dict:
        """One sample of the bank: ``u`` (6, nu), ``y`` (6, ny), leg demands (6,).

        Returns
        -------
        dict
            ``fault_class``, ``leg_action``, ``flags`` (6,) int; ``action``,
            ``faulty_leg`` int; ``safety`` bool; ``progress`` float; ``demand`` (6,);
            ``position_for_control`` (6,) (NaN if the design has none).
        """
        outs = [leg.step(u[i], y[i]) for i, leg in enumerate(self.legs)]
        fc = np.array([o["fault_class"] for o in outs], dtype=np.int64)
        sup = self.supervisor.step(fc, demand)
        pfc = np.array([o["aux"][self.pfc_index] if self.pfc_index is not None else np.nan
                        for o in outs])
        return {"fault_class": fc, "decision": sup.decision, "leg_action": sup.leg_action,
                "flags": np.array([o["flags"] for o in outs], dtype=np.int64),
                "action": sup.action, "faulty_leg": sup.faulty_leg, "safety": sup.safety,
                "progress": sup.progress, "demand": sup.demand, "position_for_control": pfc}


def supervise(design: FdiDesign, geometry: PlatformGeometry, fault_class, demand,
              safety_duration: float = DEFAULT_SAFETY_DURATION) -> dict:
    """Run the :class:`Supervisor` over whole runs of the six legs' FDI outputs.

    Parameters
    ----------
    fault_class : array_like of int, (K, 6)
        Each leg FDI's isolated class per sample.
    demand : array_like, (K, 6)
        The leg demands applied per sample (a log's ``xref`` columns).

    Returns
    -------
    dict of numpy.ndarray
        ``decision`` (K, 6), ``action`` (K,), ``faulty_leg`` (K,), ``safety`` (K,),
        ``demand_next`` (K, 6) and ``trigger_sample`` (int or None).
    """
    fc = np.asarray(fault_class, dtype=np.int64)
    dm = np.asarray(demand, dtype=float)
    K = fc.shape[0]
    sup = Supervisor(design, geometry, safety_duration)
    rec = {"decision": np.zeros((K, NLEGS), dtype=np.int64),
           "action": np.zeros(K, dtype=np.int64), "faulty_leg": np.full(K, -1, dtype=np.int64),
           "safety": np.zeros(K, dtype=bool), "demand_next": np.zeros((K, NLEGS))}
    for k in range(K):
        s = sup.step(fc[k], dm[k])
        rec["decision"][k], rec["action"][k] = s.decision, s.action
        rec["faulty_leg"][k], rec["safety"][k] = s.faulty_leg, s.safety
        rec["demand_next"][k] = s.demand
    rec["trigger_sample"] = sup.trigger_sample
    return rec


def platform_summary(design: FdiDesign, t, rec: dict, leg_summaries=None) -> dict:
    """The platform decision of a run as JSON: which leg, which class, which action, when.

    Parameters
    ----------
    design : FdiDesign
    t : array_like, (K,)
    rec : dict
        From :func:`supervise` (or the same arrays from a bank run).
    leg_summaries : list of dict, optional
        :func:`fdigen.detect.summarise_run` per leg, included as ``legs``.
    """
    t = np.asarray(t, dtype=float)
    ev = design.evaluation
    dec = np.asarray(rec["decision"])
    legs = []
    for i in range(NLEGS):
        on = np.flatnonzero(dec[:, i] != 0)
        entry = {"leg": i + 1, "fault_class": "none", "action": "none", "t_isolated": None}
        if on.size:
            c = int(dec[on[0], i])
            entry.update(fault_class=ev.classes[c], action=ev.actions[c],
                         t_isolated=float(t[on[0]]))
        if leg_summaries is not None:
            entry["fdi"] = leg_summaries[i]
        legs.append(entry)
    action = int(np.max(rec["action"])) if len(t) else 0
    faulty = int(rec["faulty_leg"][-1]) if len(t) else -1
    trig = rec.get("trigger_sample")
    if faulty >= 0:
        leg = legs[faulty]
        text = (f"leg {faulty + 1}: {leg['fault_class']} at {leg['t_isolated']:.3f} s -> "
                + {"safety_stop": "safety sequence to the rest pose",
                   "accommodate": "accommodated on the leg, platform continues",
                   "none": "no action, platform continues"}[ACTIONS[action]])
    else:
        text = "no fault isolated on any leg"
    return {"platform": {"action": ACTIONS[action],
                         "faulty_leg": faulty + 1 if faulty >= 0 else None,
                         "fault_class": legs[faulty]["fault_class"] if faulty >= 0 else "none",
                         "t_decision": legs[faulty]["t_isolated"] if faulty >= 0 else None,
                         "safety_sequence": trig is not None,
                         "t_safety_start": float(t[trig]) if trig is not None else None,
                         "legs_with_decision": [e["leg"] for e in legs
                                                if e["fault_class"] != "none"],
                         "text": text},
            "legs": legs}


def finite_json(obj):
    """``obj`` with every NaN or infinite float replaced by ``None`` (JSON ``null``), numpy
    scalars and arrays as Python numbers and lists: strict JSON (``json.dumps(...,
    allow_nan=False)``), never ``NaN`` or ``Infinity``, which JSON does not have."""
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return finite_json(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    return obj


#: The logs of a platform run in a folder, leg 1..6.
LEG_LOGS = tuple(f"leg{i}.csv" for i in range(1, NLEGS + 1))


def _reference_column(design: FdiDesign) -> str:
    """The log column of the position demand (``[simulation] reference_column``)."""
    return dict(design.model.simulation).get("reference_column", "xref")


def read_platform_logs(design: FdiDesign, folder) -> list:
    """Read ``leg1.csv`` .. ``leg6.csv`` of ``folder`` (rig format, same time base).

    Raises
    ------
    LogError
        If a log is missing or malformed, the legs' time bases differ, or a demand
        (the reference column) is NaN or infinite: the logs are read in the ``refuse``
        mode, which refuses a NaN or Inf in the columns the FDI needs, and the demands
        are the supervisor's input too (a NaN ``xref`` went through the safety
        sequence's clip and into ``--json`` output as ``NaN``).
    """
    from pathlib import Path

    from fdigen.errors import LogError
    from fdigen.sim.log import read_log
    from fdigen.sim.log_fields import nonfinite_note

    folder = Path(folder)
    if not folder.is_dir():
        raise LogError(f"{folder}: not a folder of platform logs (leg1.csv .. leg6.csv)")
    ref = _reference_column(design)
    logs = []
    for name in LEG_LOGS:
        path = folder / name
        if not path.is_file():
            raise LogError(f"{path}: missing (a platform run has {', '.join(LEG_LOGS)})")
        log = read_log(path, design.model, sample_time=design.config.sample_time,
                       extra_columns=(ref,))
        if ref in log.extra:
            bad = np.flatnonzero(~np.isfinite(log.extra[ref]))
            if bad.size:
                k = int(bad[0])
                raise LogError(f"{path}, sample {k + 1} (t = {log.t[k]:g} s), column "
                               f"{ref!r}: value is {float(log.extra[ref][k])!r} "
                               f"{nonfinite_note(False)}; {bad.size} such sample(s)")
        logs.append(log)
    t0 = logs[0].t
    for log in logs[1:]:
        if len(log.t) != len(t0) or np.max(np.abs(log.t - t0)) > 1e-9 * max(1.0, t0[-1]):
            raise LogError(f"{log.path}: time base differs from {logs[0].path} "
                           f"({len(log.t)} vs {len(t0)} samples)")
    return logs


def detect_platform(design: FdiDesign, folder, *, geometry: PlatformGeometry | None = None,
                    backend: str = "auto",
                    safety_duration: float = DEFAULT_SAFETY_DURATION) -> tuple[dict, dict]:
    """Run the six legs' FDI over a folder of platform logs, then the supervisor.

    Each leg's log goes through the single-leg FDI (:func:`fdigen.detect.fdi_runner`,
    the compiled C core by default, one call per log); the supervisor then replays the
    decisions sample by sample with the logs' ``xref`` columns as the demands in force
    (the primary sensor where a log has no ``xref``).

    Returns
    -------
    (dict, dict)
        The summary (:func:`platform_summary`, plus ``folder`` and ``backend``), and the
        raw outputs: ``t``, ``legs`` (each runner's outputs), ``record`` (of
        :func:`supervise`), ``demand`` (K, 6).
    """
    from fdigen.detect import fdi_runner, summarise_run
    from fdigen.platform.geometry import default_geometry
    from fdigen.platform.simulate import primary_output_index

    geometry = geometry or default_geometry()
    logs = read_platform_logs(design, folder)
    runner = fdi_runner(design, backend)
    ref_col = _reference_column(design)
    primary = primary_output_index(design.model)
    outs, sums, demand = [], [], []
    for log in logs:
        out = runner.run(log.u, log.y)
        outs.append(out)
        sums.append(summarise_run(design, log.t, out, str(log.path)))
        demand.append(log.extra[ref_col] if ref_col in log.extra else log.y[:, primary])
    fc = np.stack([o["fault_class"] for o in outs], axis=1)
    demand = np.stack(demand, axis=1)
    t = logs[0].t
    rec = supervise(design, geometry, fc, demand, safety_duration)
    summary = platform_summary(design, t, rec, sums)
    summary["folder"] = str(folder)
    summary["backend"] = type(runner).__name__
    summary["samples"] = int(len(t))
    if rec["trigger_sample"] is not None:
        k = rec["trigger_sample"]
        summary["safety"] = {"t_start": float(t[k]), "duration": float(safety_duration),
                             "start_positions": rec["demand_next"][k].tolist(),
                             "rest_positions": geometry.rest_positions.tolist()}
    return summary, {"t": t, "legs": outs, "record": rec, "demand": demand, "logs": logs}


def platform_figure(design: FdiDesign, raw: dict, summary: dict):
    """Six panels, one per leg: demand and primary position sensor, the leg's isolation
    time and class, the start of the safety sequence. A matplotlib ``Figure`` (no pyplot)."""
    from matplotlib.figure import Figure

    from fdigen.platform.simulate import primary_output_index

    t = raw["t"]
    primary = primary_output_index(design.model)
    fig = Figure(figsize=(10, 11), dpi=100)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.05, top=0.93, hspace=0.35)
    axes = fig.subplots(NLEGS, 1, sharex=True)
    t_safe = summary["platform"]["t_safety_start"]
    for i, ax in enumerate(axes):
        log = raw["logs"][i]
        ax.plot(t, raw["demand"][:, i] * 1e3, color="0.6", lw=1.0, label="demand xref")
        ax.plot(t, log.y[:, primary] * 1e3, color="C0", lw=0.8, label="position (primary)")
        leg = summary["legs"][i]
        title = f"leg {i + 1}: " + (f"{leg['fault_class']} at {leg['t_isolated']:.3f} s, "
                                    f"action {leg['action']}" if leg["t_isolated"] is not None
                                    else "no fault isolated")
        if leg["t_isolated"] is not None:
            ax.axvline(leg["t_isolated"], color="C3", lw=1.2, label="isolated")
        if t_safe is not None:
            ax.axvspan(t_safe, t[-1], color="C1", alpha=0.12, label="safety sequence")
        ax.set_title(title, fontsize=9, loc="left",
                     color="C3" if leg["t_isolated"] is not None else "black")
        ax.set_ylabel("x [mm]", fontsize=8)
        ax.tick_params(labelsize=7)
    handles, labels = [], []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    axes[0].legend(handles, labels, loc="upper right", fontsize=7, ncol=4, framealpha=0.9)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{summary.get('folder', '')}: {summary['platform']['text']}", fontsize=10)
    return fig
