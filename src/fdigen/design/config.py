"""The FDI design configuration (the ``[fdi]`` table of a model file), validated."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from fdigen.errors import ModelFileError
from fdigen.design.refusal_marks import (DISCOVER_REFUSAL,  # noqa: F401
                                          TUNE_REFUSAL, refused_text)
from fdigen.model.model import Model
from fdigen.model.numbers import DOUBLE_MAX, number_problem
from fdigen.model.names import check_name, check_prefixed_by_residual, model_names

ACTIONS = ("none", "accommodate", "safety_stop")
#: What ``accommodate`` does in a model without a voter (README, "`[fdi]` keys that choose
#: the residuals, and what the actions do").
ACCOMMODATE_WITHOUT_VOTER = (
    "accommodate: this model has no [fdi.voter], so the FDI core offers no substitute "
    "measurement; the decision is reported (action code 1) and the controller must "
    "accommodate itself (e.g. stop using the faulty sensor)")
#: The keys of the [fdi] table.
FDI_KEYS = ("actions", "ambiguity", "ambiguity_time", "confirm", "escalate_after_isolation",
            "extra_residuals", "frozen_horizon", "hold_windows", "innovation_filter",
            "isolate_structurally",
            "isolate_within_classes", "kalman", "nonlinear_drivers", "parity",
            "process_noise", "realign",
            "realign_noise_scale", "refused", "residual_keys", "sample_time", "startup",
            "structural_classes",
            "substeps", "thresholds",
            "unexplained_action", "voter", "window")
#: How the parity residuals' parallel models are re-aligned: one model per parity residual
#: re-aligned on its own sensor only, or one model re-aligned on every parity sensor.
REALIGN_MODES = ("dedicated", "shared")
#: Names of the residuals the design derives (numbered after the declared ``R<n>``).
DERIVED_RESIDUAL = re.compile(r"R[0-9]+\Z")


@dataclass(frozen=True)
class KalmanSpec:
    """One dedicated Kalman filter: its residual name and measured expression(s)."""

    residual: str
    measurement: str
    update: str = "measurement"  # or "voter": updated with the voter's fused sensors
    schedule: str = "operating_point"  # or "measured": prediction model scheduled on the
    #                                    measured states (see scheduled_prediction); or
    #                                    "nonlinear": through f (see nonlinear_prediction)


@dataclass(frozen=True)
class VoterSpec:
    """Broen's voter over three channels (a Kalman residual's estimate or outputs)."""

    channels: tuple[str, str, str]
    names: tuple[str, str, str]
    tolerance: float


@dataclass(frozen=True)
class FdiConfig:
    """Validated FDI settings.

    Attributes
    ----------
    sample_time : float
        Sample time [s] of the FDI step and of the ZOH discretisation.
    substeps : int
        RK4 sub-steps of the parallel model per sample.
    window : int
        Moving RMS window ``N`` of eq (22), in samples.
    confirm : int
        Samples a flag pattern must match one signature before it is isolated.
    parity : dict of str to str
        Parity residual name -> output it compares (eqs 8-10).
    realign_noise_scale : float
        Scale ``eps`` of the realignment Kalman gain's process noise, ``Q = eps^2 Q_fdi``;
        0 turns realignment off (pure parallel model).
    realign : {"dedicated", "shared"}
        ``"dedicated"`` (default): one parallel model per parity residual, re-aligned on
        that residual's own sensor only, so no parity residual is fed by another sensor
        (its sensitivity is its derived signature, ``docs/isolation.md``). ``"shared"``:
        one parallel model re-aligned on every parity sensor (mixes the sensors: a sensor
        fault leaks into the other parity residuals, outside their signatures).
    process_noise : dict of str to float
        Continuous process noise intensity (std per sqrt(s)) per state, for the Kalman filters.
    kalman : tuple of KalmanSpec
    voter : VoterSpec or None
    thresholds : dict of str to float
        RMS threshold per residual.
    frozen_horizon : dict of str to float
        Validity horizon ``H_r`` [s] per residual after the realignment freezes (the first
        flag): a flag of ``r`` rising more than ``H_r`` after the freeze is not read by the
        class decision (``docs/isolation.md``); a residual not listed has no horizon.
    actions : dict of str to str
        Action per fault class.
    extra_residuals : bool
        Whether to add the structurally derived residuals that make the fault classes
        strongly isolable.
    nonlinear_drivers : bool
        Whether a derived Kalman filter whose driver (a measured state its sub-model reads
        as an input) enters ``f`` nonlinearly predicts through ``f``
        (:func:`~fdigen.design.nonlinear_prediction.nonlinear_reason`).
    isolate_within_classes : int
        At most this many further residuals that separate faults of the same class
        (0: none).
    structural_classes : bool
        Whether those structural residuals decide classes too (default: they name faults
        only, ``docs/isolation.md`` section 4; ``fdigen tune`` and ``fdigen commission``
        try it when a campaign leaves faults it would make class-isolable unisolated,
        :mod:`fdigen.tune.class_search`).
    isolate_structurally : bool
        Whether to add, from the same candidates, the residuals that bring the signature
        table to the isolability the model's structure allows
        (:mod:`fdigen.design.structural_selection`).
    ambiguity : {"most_severe", "wait"}
        Action while the flags leave several classes consistent: the most severe of their
        actions once the ambiguity has lasted ``confirm`` samples, or (``"wait"``) only an
        action every consistent class calls for (``docs/isolation.md``).
    ambiguity_time : float or None
        Seconds the most severe action of several consistent classes must hold before it
        is taken (None: ``confirm`` samples); a unanimous action waits ``confirm``.
    unexplained_action : str
        Action when a flag contradicts the isolated class, or every declared fault.
    escalate_after_isolation : bool
        Whether a flag the isolated class cannot explain escalates to ``unexplained``
        (flags no declared fault explains before any isolation always do).
    hold_windows : int
        When not 0, a frozen parallel model keeps applying the mean of its realignment
        correction over about this many RMS windows
        (:func:`fdigen.design.parallel_model.parallel_block`) instead of none; 0 (the
        default): off (``docs/isolation.md``, section 13).
    innovation_filter : float
        Time constant in seconds of a first-order low-pass on the innovation of every
        derived Kalman residual before its RMS (:mod:`fdigen.design.innovation_filter`);
        0: off.
    startup : float
        Seconds from the core's first sample (and from every restart) during which it
        raises no flag: its observers and parallel models settle from the operating point
        to a plant whose hidden states start elsewhere (a battery's state of charge).
        0 (the default): flags from the first sample.
    refused : str
        Why ``fdigen commission`` refused this design (it writes the key into the
        commissioned file), or why ``fdigen tune --write`` did (its thresholds failed
        their own validation; the text begins with :data:`TUNE_REFUSAL`): ``detect``,
        ``build`` and ``inspect`` say so before anything else. ``""``: the key is
        absent (an empty or blank value reads "(no reason given)": the key, not its text,
        refuses). Deleting the key is the engineer's acceptance.
    """

    sample_time: float
    substeps: int
    window: int
    confirm: int
    parity: dict
    realign_noise_scale: float
    process_noise: dict
    kalman: tuple
    voter: VoterSpec | None
    thresholds: dict
    actions: dict
    extra_residuals: bool = True
    nonlinear_drivers: bool = False
    isolate_within_classes: int = 0
    isolate_structurally: bool = True
    structural_classes: bool = False
    frozen_horizon: dict = field(default_factory=dict)
    residual_keys: dict = field(default_factory=dict)
    realign: str = "dedicated"
    ambiguity: str = "most_severe"
    unexplained_action: str = "safety_stop"
    escalate_after_isolation: bool = True
    ambiguity_time: float | None = None
    hold_windows: int = 0
    innovation_filter: float = 0.0
    startup: float = 0.0
    refused: str = ""


def read_fdi_config(model: Model) -> FdiConfig:
    """Validate ``model.fdi`` and return an :class:`FdiConfig`.

    Every key is typed (integers must be TOML integers, booleans TOML booleans), every
    table refuses unknown keys, every residual and class name is checked as a name
    (:mod:`fdigen.model.names`), and missing thresholds or actions are listed all at once.

    Raises
    ------
    ModelFileError
        Naming the field, for any missing, mistyped or out-of-range setting.
    """
    raw = dict(model.fdi)
    src = model.source

    def err(msg, fld, sym=None):
        return ModelFileError(msg, source=src, field=f"fdi.{fld}" if fld else "fdi", symbol=sym)

    def number(key, default=None, lo=None, hi=None, table=raw, prefix=""):
        value = table.get(key, default)
        if value is None:
            raise err("missing setting", prefix + key)
        problem = number_problem(value, DOUBLE_MAX)
        if problem:
            raise err(problem, prefix + key, key)
        value = float(value)
        if not math.isfinite(value) or (lo is not None and value <= lo) or (
                hi is not None and value > hi):
            raise err(f"value {value} out of range ({lo}, {hi}]", prefix + key)
        return value

    def integer(key, default, lo, hi):
        value = raw.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise err(f"expected an integer, got {type(value).__name__} {str(value)[:30]}",
                      key, str(value)[:30])
        if not lo <= value <= hi:
            shown = str(value) if abs(value) < 10**30 else f"of {len(str(abs(value)))} digits"
            raise err(f"value {shown} out of range [{lo}, {hi}]", key, key)
        return value

    def table(key, parent=raw, prefix=""):
        value = parent.get(key, {})
        if not isinstance(value, dict):
            raise err("must be a table", prefix + key)
        return value

    def unknown(tab, allowed, fld):
        extra = sorted(set(tab) - set(allowed))
        if extra:
            raise err(f"unknown key (allowed: {', '.join(allowed)})", fld, extra[0])

    taken = model_names(model)

    def residual_names(keys, fld):
        for key in keys:
            check_name(key, source=src, field=f"fdi.{fld}", kind="residual name",
                       model_name=model.name)
            if key in taken:
                # a pump's residual Rp beside its pipe-loss parameter Rp: inspect printed
                # "-2*q*(Rp + aq)/Ip" in the row of the residual Rp (round 41)
                raise err(f"a residual named like the model's {taken[key]} {key}: the "
                          "tables and equations could not tell them apart; rename the "
                          "residual", f"{fld}.{key}", key)
        return keys

    if not raw:
        raise err("the model has no [fdi] table", None)
    unknown(raw, FDI_KEYS, None)
    outputs = {o.name for o in model.outputs}
    states = {s.name for s in model.states}
    dt = number("sample_time", lo=0.0, hi=3600.0)   # a building: 60-900 s
    substeps = integer("substeps", 1, 1, 1000)
    window = integer("window", 100, 1, 100000)
    confirm = integer("confirm", 1, 1, 1000000)
    parity = residual_names(table("parity"), "parity")
    for rname, out in parity.items():
        if not isinstance(out, str) or out not in outputs:
            raise err("parity residual compares an unknown output", f"parity.{rname}",
                      str(out)[:40])
    realign = number("realign_noise_scale", 0.0, hi=1e6)
    if realign < 0:
        raise err("must be >= 0", "realign_noise_scale")
    lowpass = number("innovation_filter", 0.0, hi=1e6)
    if lowpass < 0:
        raise err("must be >= 0 (seconds; 0: off)", "innovation_filter", str(lowpass))
    realign_mode = raw.get("realign", "dedicated")
    if realign_mode not in REALIGN_MODES:
        raise err(f"must be one of {', '.join(REALIGN_MODES)}", "realign", str(realign_mode)[:30])
    pnoise = table("process_noise")
    missing = [s.name for s in model.states if s.name not in pnoise]
    if missing:
        raise err(f"missing process noise for states {', '.join(missing)}", "process_noise",
                  missing[0])
    for sname in pnoise:
        if sname not in states:
            raise err("process noise for an unknown state", "process_noise", str(sname)[:40])
        if number(sname, table=pnoise, prefix="process_noise.") < 0:
            raise err("process noise must be >= 0", f"process_noise.{sname}", sname)
    kal = []
    for rname, spec in residual_names(table("kalman"), "kalman").items():
        if not isinstance(spec, dict) or not isinstance(spec.get("measurement"), str):
            raise err("a Kalman filter needs a measurement (an expression of outputs)",
                      f"kalman.{rname}", rname)
        unknown(spec, ("measurement", "schedule", "update"), f"kalman.{rname}")
        upd = spec.get("update", "measurement")
        if upd not in ("measurement", "voter"):
            raise err("update must be 'measurement' or 'voter'", f"kalman.{rname}.update",
                      str(upd)[:40])
        sched = spec.get("schedule", "operating_point")
        if sched not in ("operating_point", "measured", "nonlinear"):
            raise err("schedule must be 'operating_point', 'measured' or 'nonlinear'",
                      f"kalman.{rname}.schedule", str(sched)[:40])
        kal.append(KalmanSpec(rname, spec["measurement"], upd, sched))
    voter = None
    if "voter" in raw:
        v = table("voter")
        unknown(v, ("channels", "names", "tolerance"), "voter")
        ch = v.get("channels", [])
        names = v.get("names", ["w1", "w2", "w3"])
        if not isinstance(ch, list) or len(ch) != 3:
            raise err("a voter has exactly three channels", "voter.channels")
        if not isinstance(names, list) or len(names) != 3:
            raise err("a voter has exactly three names", "voter.names")
        residual_names(names, "voter.names")
        kal_names = {k.residual for k in kal}
        for c in ch:
            if not isinstance(c, str) or (c not in outputs and c not in kal_names):
                raise err("voter channel must be an output or a Kalman residual's estimate",
                          "voter.channels", str(c)[:40])
        tol = number("tolerance", table=v, lo=0.0, prefix="voter.")
        voter = VoterSpec(tuple(ch), tuple(names), tol)
    names = list(parity) + [k.residual for k in kal] + (list(voter.names) if voter else [])
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise err("residual names must be unique (parity, kalman and voter names)", "parity",
                  dup[0])
    symbols = [(kind, item.name) for kind, items in (
        ("states", model.states), ("inputs", model.inputs), ("outputs", model.outputs),
        ("parameters", model.parameters), ("faults", model.faults))
        for item in items] + [("definitions", n) for n, _ in model.definitions]
    check_prefixed_by_residual(symbols, names, source=src)
    thresholds = dict(table("thresholds"))
    missing = [n for n in names if n not in thresholds]
    if missing:
        exc = err(f"missing thresholds for residuals {', '.join(missing)} (`fdigen tune "
                  "--model FILE --write` designs them)", "thresholds", missing[0])
        exc.missing_thresholds = tuple(missing)     # what `fdigen tune` fills in
        raise exc
    for rname in thresholds:
        if rname not in names and not DERIVED_RESIDUAL.match(str(rname)):
            raise err("threshold for an unknown residual (residuals: "
                      f"{', '.join(names)}, or R<n> for a derived one)", "thresholds",
                      str(rname)[:40])
        number(rname, table=thresholds, lo=0.0, prefix="thresholds.")
    horizon = dict(table("frozen_horizon"))
    for rname in horizon:
        if rname not in names and not DERIVED_RESIDUAL.match(str(rname)):
            raise err("frozen horizon for an unknown residual (residuals: "
                      f"{', '.join(names)}, or R<n> for a derived one)", "frozen_horizon",
                      str(rname)[:40])
        # 0: every flag after the freeze is late (a residual already above its threshold
        # when the parallel models froze; tune wrote it, and the file failed to load)
        if horizon[rname] != 0 or isinstance(horizon[rname], bool):
            number(rname, table=horizon, lo=0.0, prefix="frozen_horizon.")
    keys = dict(table("residual_keys"))
    for rname, key in keys.items():
        if not DERIVED_RESIDUAL.match(str(rname)) or rname in names:
            raise err("a residual key is for a derived residual (R<n>, not one of "
                      f"{', '.join(names)})", "residual_keys", str(rname)[:40])
        if not isinstance(key, str):
            raise err("a residual key is a text (written by `fdigen tune --write`)",
                      f"residual_keys.{rname}", str(key)[:40])
        if rname not in thresholds:
            raise err("a residual key without a threshold", f"residual_keys.{rname}", rname)
    classes = sorted({f.fault_class for f in model.faults})
    actions = dict(table("actions"))
    for cname in actions:
        if cname not in classes:
            raise err(f"action for an unknown fault class (classes: {', '.join(classes)})",
                      "actions", str(cname)[:40])
    missing = [c for c in classes if c not in actions]
    if missing:
        raise err(f"missing actions for fault classes {', '.join(missing)}", "actions",
                  missing[0])
    for cname, act in actions.items():
        if act not in ACTIONS:
            raise err(f"action must be one of {ACTIONS}", f"actions.{cname}", str(act)[:40])
    if "unexplained" in classes:
        raise err("fault class name 'unexplained' is reserved (flags no declared fault "
                  "explains)", "actions", "unexplained")
    ambiguity = raw.get("ambiguity", "most_severe")
    if ambiguity not in ("most_severe", "wait"):
        raise err("ambiguity must be 'most_severe' or 'wait'", "ambiguity", str(ambiguity)[:40])
    unexplained = raw.get("unexplained_action", "safety_stop")
    if unexplained not in ACTIONS:
        raise err(f"unexplained_action must be one of {ACTIONS}", "unexplained_action",
                  str(unexplained)[:40])
    def boolean(key, default):
        value = raw.get(key, default)
        if not isinstance(value, bool):
            raise err(f"expected a boolean (true or false), got {type(value).__name__}",
                      key, str(value)[:30])
        return value

    extra = boolean("extra_residuals", True)
    return FdiConfig(
        sample_time=dt, substeps=substeps, window=window, confirm=confirm, parity=dict(parity),
        realign_noise_scale=realign, process_noise={k: float(v) for k, v in pnoise.items()},
        kalman=tuple(kal), voter=voter, thresholds={k: float(v) for k, v in thresholds.items()},
        actions=actions, extra_residuals=extra,
        nonlinear_drivers=boolean("nonlinear_drivers", False),
        isolate_within_classes=integer("isolate_within_classes", 0, 0, 64),
        isolate_structurally=boolean("isolate_structurally", True),
        structural_classes=boolean("structural_classes", False),
        frozen_horizon={k: float(v) for k, v in horizon.items()},
        residual_keys={str(k): str(v) for k, v in keys.items()}, realign=realign_mode,
        ambiguity=ambiguity, unexplained_action=unexplained,
        escalate_after_isolation=boolean("escalate_after_isolation", True),
        hold_windows=integer("hold_windows", 0, 0, 1000),
        innovation_filter=lowpass,
        ambiguity_time=(number("ambiguity_time", lo=0.0, hi=1e9)
                        if "ambiguity_time" in raw else None),
        startup=_startup(raw, number, err, dt),
        refused=(_refusal_text(raw["refused"], err) or "(no reason given)"
                 if "refused" in raw else ""))


def _startup(raw, number, err, dt: float) -> float:
    """``[fdi] startup``: seconds, 0 or more, at most ``2^31 - 1`` samples."""
    if "startup" not in raw:
        return 0.0
    value = number("startup", hi=1e12)
    if value < 0 or value / dt > 2**31 - 1:
        raise err(f"must be 0 or more seconds, at most 2^31 - 1 samples of {dt:g} s (the "
                  "core's start-up without flags)", "startup", str(raw["startup"])[:30])
    return value


def _refusal_text(value, err) -> str:
    """``[fdi] refused``: a string of printable text (it is printed, never executed)."""
    if not isinstance(value, str):
        raise err("must be a string (why `fdigen commission` or `fdigen tune` refused the "
                  "design)",
                  "refused", None)
    if len(value) > 4000 or not value.isprintable():
        raise err("must be printable text on one line, of at most 4000 characters "
                  "(a newline could fake a line of the commands' output)", "refused", None)
    return value

