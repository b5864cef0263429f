"""The FDI design configuration (the ``[fdi]`` table of a model file), validated."""

from __future__ import annotations

import math
from dataclasses import dataclass

from fdigen.errors import ModelFileError
from fdigen.model.model import Model

ACTIONS = ("none", "accommodate", "safety_stop")


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
    process_noise : dict of str to float
        Continuous process noise intensity (std per sqrt(s)) per state, for the Kalman filters.
    kalman : tuple of KalmanSpec
    voter : VoterSpec or None
    thresholds : dict of str to float
        RMS threshold per residual.
    actions : dict of str to str
        Action per fault class.
    extra_residuals : bool
        Whether to add the structurally derived residuals that make the fault classes
        strongly isolable.
    isolate_within_classes : int
        At most this many further residuals that separate faults of the same class
        (0: none).
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
    isolate_within_classes: int = 0


def read_fdi_config(model: Model) -> FdiConfig:
    """Validate ``model.fdi`` and return an :class:`FdiConfig`.

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
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise err("expected a number", prefix + key, str(value)[:30])
        value = float(value)
        if not math.isfinite(value) or (lo is not None and value <= lo) or (
                hi is not None and value > hi):
            raise err(f"value {value} out of range ({lo}, {hi}]", prefix + key)
        return value

    if not raw:
        raise err("the model has no [fdi] table", None)
    outputs = {o.name for o in model.outputs}
    states = {s.name for s in model.states}
    dt = number("sample_time", lo=0.0, hi=10.0)
    substeps = int(number("substeps", 1, lo=0, hi=1000))
    window = int(number("window", 100, lo=1, hi=100000))
    confirm = int(number("confirm", 1, lo=0, hi=1e6))
    parity = raw.get("parity", {})
    if not isinstance(parity, dict):
        raise err("must be a table residual = output", "parity")
    for rname, out in parity.items():
        if out not in outputs:
            raise err("parity residual compares an unknown output", f"parity.{rname}", out)
    realign = number("realign_noise_scale", 0.0, hi=1e6)
    if realign < 0:
        raise err("must be >= 0", "realign_noise_scale")
    pnoise = raw.get("process_noise", {})
    for sname in states:
        if sname not in pnoise:
            raise err("missing process noise for state", "process_noise", sname)
    for sname, value in pnoise.items():
        if sname not in states:
            raise err("process noise for an unknown state", "process_noise", sname)
        number(sname, table=pnoise, prefix="process_noise.")
        if value < 0:
            raise err("process noise must be >= 0", f"process_noise.{sname}", sname)
    kal = []
    for rname, spec in raw.get("kalman", {}).items():
        if not isinstance(spec, dict) or "measurement" not in spec:
            raise err("a Kalman filter needs a measurement", f"kalman.{rname}", rname)
        upd = spec.get("update", "measurement")
        if upd not in ("measurement", "voter"):
            raise err("update must be 'measurement' or 'voter'", f"kalman.{rname}.update", upd)
        sched = spec.get("schedule", "operating_point")
        if sched not in ("operating_point", "measured", "nonlinear"):
            raise err("schedule must be 'operating_point', 'measured' or 'nonlinear'",
                      f"kalman.{rname}.schedule", sched)
        unknown = set(spec) - {"measurement", "update", "schedule"}
        if unknown:
            raise err("unknown key (allowed: measurement, schedule, update)",
                      f"kalman.{rname}", sorted(unknown)[0])
        kal.append(KalmanSpec(rname, str(spec["measurement"]), upd, sched))
    voter = None
    if "voter" in raw:
        v = raw["voter"]
        ch = v.get("channels", [])
        names = v.get("names", ["w1", "w2", "w3"])
        if len(ch) != 3 or len(names) != 3:
            raise err("a voter has exactly three channels and three names", "voter.channels")
        kal_names = {k.residual for k in kal}
        for c in ch:
            if c not in outputs and c not in kal_names:
                raise err("voter channel must be an output or a Kalman residual's estimate",
                          "voter.channels", c)
        tol = number("tolerance", table=v, lo=0.0, prefix="voter.")
        voter = VoterSpec(tuple(ch), tuple(names), tol)
    names = list(parity) + [k.residual for k in kal] + (list(voter.names) if voter else [])
    if len(set(names)) != len(names):
        raise err("residual names must be unique", "parity")
    thresholds = dict(raw.get("thresholds", {}))
    for rname in names:
        if rname not in thresholds:
            raise err("missing threshold for residual", "thresholds", rname)
    for rname in thresholds:
        number(rname, table=thresholds, lo=0.0, prefix="thresholds.")
    classes = {f.fault_class for f in model.faults}
    actions = dict(raw.get("actions", {}))
    for cname in classes:
        if cname not in actions:
            raise err("missing action for fault class", "actions", cname)
    for cname, act in actions.items():
        if act not in ACTIONS:
            raise err(f"action must be one of {ACTIONS}", f"actions.{cname}", act)
    return FdiConfig(
        sample_time=dt, substeps=substeps, window=window, confirm=confirm, parity=dict(parity),
        realign_noise_scale=realign, process_noise={k: float(v) for k, v in pnoise.items()},
        kalman=tuple(kal), voter=voter, thresholds={k: float(v) for k, v in thresholds.items()},
        actions=actions, extra_residuals=bool(raw.get("extra_residuals", True)),
        isolate_within_classes=int(number("isolate_within_classes", 0, hi=64)))
