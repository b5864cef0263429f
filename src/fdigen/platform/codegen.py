"""The platform's FDI bank as generated C99: ``<model>_platform_step`` for all six legs.

:func:`render_platform_sources` renders ``templates/c_platform/platform_fdi.{h,c}.j2``
(through :func:`fdigen.backends.render.render`, like every generated file) beside the
single-leg library of :func:`fdigen.backends.c.render_c_sources`. The generated step calls
``<model>_fdi_step`` once per leg and then runs the supervisor of
:mod:`fdigen.platform.supervisor` -- per-leg decisions, platform action, faulty leg and
the quintic safety sequence towards the rest positions, which are precomputed here by
inverse kinematics of the geometry's rest pose and written into the C as constants.

:class:`PlatformCFdi` compiles the four files into a shared library (cached by content)
and drives it through ctypes with the interface of
:class:`fdigen.platform.supervisor.PlatformFdi` (``reset``, ``step``) plus a whole-run
``run`` in one C call.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

from fdigen.backends.c.emit import _comment, render_c_sources
from fdigen.backends.c.loader import build_shared_library, state_fields
from fdigen.backends.c.printer import FdiCPrinter
from fdigen.backends.render import render
from fdigen.design.config import ACTIONS
from fdigen.design.fdi_design import FdiDesign
from fdigen.files.atomic import write_text
from fdigen.model.model_file import model_hash as _model_hash
from fdigen.platform.geometry import NLEGS, PlatformGeometry, default_geometry
from fdigen.platform.supervisor import (DEFAULT_SAFETY_DURATION, SAFETY,
                                        check_safety_duration)

#: The platform templates, under ``templates/``.
TEMPLATES = {"h": "c_platform/platform_fdi.h.j2", "c": "c_platform/platform_fdi.c.j2"}


def platform_names(model_name: str) -> dict:
    """C prefix, macro prefix and file names of the platform library."""
    prefix = f"{model_name}_platform"
    return {"prefix": prefix, "macro": prefix.upper(), "header": f"{prefix}_fdi.h",
            "source": f"{prefix}_fdi.c", "leg": f"{model_name}_fdi",
            "leg_macro": f"{model_name}_fdi".upper(), "leg_header": f"{model_name}_fdi.h"}


def platform_context(design: FdiDesign, geometry: PlatformGeometry,
                     safety_duration: float = DEFAULT_SAFETY_DURATION,
                     float_type: str = "double") -> dict:
    """Template context of the platform C (everything already printed as C text).

    Raises
    ------
    FdigenError
        If the safety duration is out of its range (:func:`~fdigen.platform.supervisor.
        check_safety_duration`: at least one sample time, and a normal number of the real
        type), or the design has no action ``safety_stop`` to trigger the safety sequence
        with.
    """
    safety_duration = check_safety_duration(safety_duration, design.config.sample_time,
                                            float_type)
    pr = FdiCPrinter(float_type)
    names = platform_names(design.name)
    aux = design.aux_names
    pfc = aux.index("position_for_control") if "position_for_control" in aux else None
    from fdigen.platform.simulate import primary_output_index

    primary = primary_output_index(design.model)
    rest = geometry.rest
    return {
        **names, "real": f"{design.name}_real", "nlegs": NLEGS,
        "actions": list(ACTIONS), "safety_code": SAFETY,
        "class_action": list(design.evaluation.action_codes),
        "stroke": pr.literal(geometry.stroke), "l_min": pr.literal(geometry.l_min),
        "safety_duration": pr.literal(safety_duration),
        "rest_length": [pr.literal(v) for v in geometry.rest_lengths],
        "rest_position": [pr.literal(v) for v in geometry.rest_positions],
        "pfc_index": pfc, "primary_index": primary,
        "pfc_text": ("each leg's position for its controller (aux position_for_control: "
                     "the voter's output once accommodated)" if pfc is not None else
                     "each leg's primary position sensor"),
        "geometry_text": _comment(
            f"leg length l_i = |p + R b_i - a_i| with R = Rz(yaw) Ry(pitch) Rx(roll), "
            f"piston x_i = l_i - L_MIN in [0, stroke]; rest pose "
            + ", ".join(f"{n} = {v:.6g}" for n, v in zip(
                ("surge", "sway", "heave", "roll", "pitch", "yaw"), rest))
            + " (relative to home)"),
    }


def render_platform_sources(design: FdiDesign, geometry: PlatformGeometry | None = None, *,
                            safety_duration: float = DEFAULT_SAFETY_DURATION,
                            float_type: str = "double", model_source: str | None = None,
                            model_hash: str | None = None) -> dict[str, str]:
    """The single-leg library and the platform bank, as text.

    Parameters
    ----------
    design : FdiDesign
        The single-leg design.
    geometry : PlatformGeometry, optional
        Default :func:`~fdigen.platform.geometry.default_geometry`.
    safety_duration : float
        Default ``T`` of the safety sequence [s] (a run-time parameter of the C).
    float_type : {"double", "float"}
    model_source, model_hash : str, optional
        For the preambles (default: the model file's name and hash).

    Returns
    -------
    dict of str to str
        ``<m>_fdi.h``, ``<m>_fdi.c``, ``<m>_platform_fdi.h``, ``<m>_platform_fdi.c``.
    """
    geometry = geometry or default_geometry()
    model = design.model
    model_source = model_source or Path(str(model.source)).name
    model_hash = model_hash or _model_hash(model)
    leg = render_c_sources(design, float_type=float_type, model_source=model_source,
                           model_hash=model_hash)
    names = platform_names(design.name)
    files = {names["leg_header"]: leg[names["leg_header"]],
             f"{names['leg']}.c": leg[f"{names['leg']}.c"]}
    ctx = platform_context(design, geometry, safety_duration, float_type)
    for key, fname in (("h", names["header"]), ("c", names["source"])):
        files[fname] = render(TEMPLATES[key], comment="//", model_name=design.name,
                              model_source=model_source, model_hash=model_hash, **ctx)
    return files


def write_platform_sources(design: FdiDesign, folder: str | Path, *, force: bool = False,
                           **kwargs) -> list[Path]:
    """Write :func:`render_platform_sources` into ``folder`` (created if needed); a file of
    the same name that fdigen did not write is refused unless ``force``
    (:func:`fdigen.files.outputs.check_own_outputs`)."""
    from fdigen.files.outputs import check_own_outputs

    folder = Path(folder)
    sources = render_platform_sources(design, **kwargs)
    check_own_outputs([folder / name for name in sources], "-o", force)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name, text in sources.items():
        write_text(folder / name, text)   # atomic, symbolic links followed
        out.append(folder / name)
    return out


_CTYPES = {"double": (ctypes.c_double, np.float64), "float": (ctypes.c_float, np.float32)}


class PlatformCFdi:
    """The generated platform bank, compiled and loaded with ctypes.

    Parameters
    ----------
    design : FdiDesign
    geometry : PlatformGeometry, optional
    safety_duration : float
    parameters : dict or sequence of 6 dict, optional
        Model parameter overrides (all legs, or per leg).
    float_type : {"double", "float"}
    cc : str
    cache_dir : str or Path, optional
        Where the built library is cached (see :func:`build_shared_library`).
    """

    def __init__(self, design: FdiDesign, geometry: PlatformGeometry | None = None,
                 safety_duration: float = DEFAULT_SAFETY_DURATION, parameters=None,
                 float_type: str = "double", cc: str = "gcc", cache_dir=None):
        if float_type not in _CTYPES:
            raise ValueError(f"float_type must be one of {sorted(_CTYPES)}, got {float_type!r}")
        self.design = design
        self.geometry = geometry or default_geometry()
        model = design.model
        self.names = platform_names(design.name)
        self.real, self.dtype = _CTYPES[float_type]
        self.sources = render_platform_sources(design, self.geometry,
                                               safety_duration=safety_duration,
                                               float_type=float_type)
        self.library_path = build_shared_library(self.sources, self.names["prefix"], cc=cc,
                                                 cache_dir=cache_dir)
        self.lib = ctypes.CDLL(str(self.library_path))
        self.nu, self.ny = len(model.inputs), len(model.outputs)
        self.nz, self.nr = len(design.state_names), len(design.residual_names)
        self.naux = len(design.aux_names)
        self._declare()
        self.params = self._Params()
        self._call("default_params", ctypes.byref(self.params))
        values = {q.name: q.value for q in model.parameters}
        per_leg = ([dict(parameters or {})] * NLEGS if parameters is None
                   or isinstance(parameters, dict) else list(parameters))
        for i, d in enumerate(per_leg):
            unknown = set(d) - set(values)
            if unknown:
                raise ValueError(f"leg {i + 1}: unknown parameter(s) {sorted(unknown)}")
            for k, v in d.items():
                setattr(self.params.leg[i], k, v)
        self.params.safety_duration = safety_duration
        self.state = self._State()
        status = self._fn("init")(ctypes.byref(self.state), ctypes.byref(self.params))
        if status != 0:
            raise ValueError(f"{self.names['prefix']}_init failed with status {status}")
        self._u = np.zeros((NLEGS, self.nu), dtype=self.dtype)
        self._y = np.zeros((NLEGS, self.ny), dtype=self.dtype)
        self._d = np.zeros(NLEGS, dtype=self.dtype)
        self._out = self._Output()

    def _fn(self, name):
        return getattr(self.lib, f"{self.names['prefix']}_{name}")

    def _call(self, name, *args):
        status = self._fn(name)(*args)
        if status < 0:
            raise RuntimeError(f"{self.names['prefix']}_{name} failed with status {status}")
        return status

    def _declare(self):
        real, d = self.real, lambda n: max(n, 1)
        nr, window = d(self.nr), self.design.evaluation.window
        leg_params = type("LegParams", (ctypes.Structure,), {
            "_fields_": [(q.name, real) for q in self.design.model.parameters]})
        leg_state = type("LegState", (ctypes.Structure,), {
            "_fields_": state_fields(real, d(self.nz), nr, window,
                                     self.design.evaluation.startup)})
        leg_output = type("LegOutput", (ctypes.Structure,), {"_fields_": [
            ("r", real * nr), ("rms", real * nr), ("flags", ctypes.c_uint32),
            ("fault_class", ctypes.c_int32), ("action", ctypes.c_int32),
            ("aux", real * d(self.naux)), ("faults", ctypes.c_uint32)]})
        i32 = ctypes.c_int32
        self._Params = type("PlatformParams", (ctypes.Structure,), {"_fields_": [
            ("leg", leg_params * NLEGS), ("stroke", real), ("rest_position", real * NLEGS),
            ("safety_duration", real)]})
        self._State = type("PlatformState", (ctypes.Structure,), {"_fields_": [
            ("leg", leg_state * NLEGS), ("decision", i32 * NLEGS), ("level", i32),
            ("faulty_leg", i32), ("safety", i32), ("n", i32), ("start", real * NLEGS),
            ("demand", real * NLEGS)]})
        self._Output = type("PlatformOutput", (ctypes.Structure,), {"_fields_": [
            ("leg", leg_output * NLEGS), ("decision", i32 * NLEGS),
            ("leg_action", i32 * NLEGS), ("action", i32), ("faulty_leg", i32),
            ("safety", i32), ("progress", real), ("demand", real * NLEGS),
            ("position_for_control", real * NLEGS)]})
        vp, rp = ctypes.c_void_p, ctypes.POINTER(real)
        ip = ctypes.POINTER(i32)
        for name, args in {"default_params": [vp], "check_params": [vp], "init": [vp, vp],
                           "reset": [vp, vp], "set_demand": [vp, rp],
                           "step": [vp, vp, vp, vp, vp],
                           "run": [vp, vp, ctypes.c_long, rp, rp, rp, ip, ip, ip, ip, ip,
                                   rp, rp]}.items():
            fn = self._fn(name)
            fn.argtypes, fn.restype = args, ctypes.c_int

    def _ptr(self, arr):
        return arr.ctypes.data_as(ctypes.POINTER(self.real))

    @property
    def struct_sizes(self) -> dict:
        """``sizeof`` of the ctypes mirrors of the params, state and output structs."""
        return {"params": ctypes.sizeof(self._Params), "state": ctypes.sizeof(self._State),
                "output": ctypes.sizeof(self._Output)}

    def reset(self):
        """Forget everything (leg FDIs and supervisor); demands back at rest."""
        self._call("reset", ctypes.byref(self.state), ctypes.byref(self.params))

    def step(self, u, y, demand) -> dict:
        """``set_demand`` then one ``<m>_platform_step``; the dict of
        :meth:`fdigen.platform.supervisor.PlatformFdi.step`."""
        self._u[...] = np.reshape(u, (NLEGS, self.nu))
        self._y[...] = np.reshape(y, (NLEGS, self.ny))
        self._d[...] = demand
        self._fn("set_demand")(ctypes.byref(self.state), self._ptr(self._d))
        out = self._out
        self._call("step", ctypes.byref(self.state), ctypes.byref(self.params),
                   self._u.ctypes.data, self._y.ctypes.data, ctypes.byref(out))
        dec = np.frombuffer(out.decision, dtype=np.int32).astype(np.int64)
        return {"fault_class": np.array([out.leg[i].fault_class for i in range(NLEGS)],
                                        dtype=np.int64),
                "decision": dec,
                "leg_action": np.frombuffer(out.leg_action, dtype=np.int32).astype(np.int64),
                "flags": np.array([out.leg[i].flags for i in range(NLEGS)], dtype=np.int64),
                "action": int(out.action), "faulty_leg": int(out.faulty_leg),
                "safety": bool(out.safety), "progress": float(out.progress),
                "demand": np.array(out.demand[:], dtype=float),
                "position_for_control": np.array(out.position_for_control[:], dtype=float)}

    def run(self, u, y, demand=None, *, reset: bool = True) -> dict:
        """The bank over a whole run in one C call.

        Parameters
        ----------
        u : array_like, (K, 6, nu)
        y : array_like, (K, 6, ny)
        demand : array_like, (K, 6), optional
            Leg demands applied per sample (a run's ``xref``).
        reset : bool
            Start from a reset bank.

        Returns
        -------
        dict of numpy.ndarray
            ``decision``, ``flags`` (K, 6); ``action``, ``faulty_leg`` (K,); ``safety``
            (K,) bool; ``demand_next``, ``position_for_control`` (K, 6); and
            ``trigger_sample``.
        """
        u = np.ascontiguousarray(u, dtype=self.dtype)
        K = u.shape[0]
        u = u.reshape(K, NLEGS, self.nu)
        y = np.ascontiguousarray(y, dtype=self.dtype).reshape(K, NLEGS, self.ny)
        dm = None if demand is None else np.ascontiguousarray(demand, dtype=self.dtype
                                                              ).reshape(K, NLEGS)
        ints = {k: np.zeros(s, dtype=np.int32) for k, s in
                (("decision", (K, NLEGS)), ("flags", (K, NLEGS)), ("action", K),
                 ("faulty_leg", K), ("safety", K))}
        reals = {k: np.zeros((K, NLEGS), dtype=self.dtype)
                 for k in ("demand_next", "position_for_control")}
        ip = ctypes.POINTER(ctypes.c_int32)
        if reset:
            self.reset()
        self._call("run", ctypes.byref(self.state), ctypes.byref(self.params), K,
                   None if dm is None else self._ptr(dm), self._ptr(u), self._ptr(y),
                   *(ints[k].ctypes.data_as(ip) for k in ("decision", "flags", "action",
                                                           "faulty_leg", "safety")),
                   *(self._ptr(reals[k]) for k in ("demand_next", "position_for_control")))
        out = {k: v.astype(np.int64) for k, v in ints.items()}
        out["safety"] = ints["safety"].astype(bool)
        out.update({k: v.astype(np.float64) for k, v in reals.items()})
        on = np.flatnonzero(out["safety"])
        out["trigger_sample"] = int(on[0]) if on.size else None
        return out
