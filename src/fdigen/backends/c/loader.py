"""Compile the generated C into a shared library and drive it through ctypes.

:class:`CFdi` has the interface of :class:`fdigen.backends.reference.ReferenceFdi`
(``core``, ``step``, ``reset``, ``run``), so the generated C can be checked against the
reference sample for sample. ``run`` makes one ctypes call for a whole log.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from fdigen.backends.c.emit import render_c_sources
from fdigen.design.fdi_design import FdiDesign
from fdigen.files.trust import untrusted_reason
from fdigen.model.model_file import model_hash

#: Flags of the shared library: optimised, strict IEEE (no contraction into FMA).
SHARED_FLAGS = ("-std=c99", "-O2", "-fPIC", "-shared", "-ffp-contract=off")

_CTYPES = {"double": (ctypes.c_double, np.float64), "float": (ctypes.c_float, np.float32)}


_PRIVATE_ROOT: list = []    # the process's own folder when the shared one is not usable


def _cache_root() -> Path:
    """The folder of compiled C libraries: ``<tmp>/fdigen-c-<uid>`` when it is private to
    the user (owner and mode: a planted library would run). When it is not (another user
    created that predictable path first), a warning and a fresh private folder for this
    process: the C backend stays usable, nothing is loaded from the foreign folder."""
    root = Path(tempfile.gettempdir()) / f"fdigen-c-{os.getuid()}"
    try:
        root.mkdir(mode=0o700, exist_ok=True)
        reason = untrusted_reason(root)
    except OSError as exc:
        reason = f"{root}: {exc.strerror or exc}"
    if reason is None:
        return root
    if not _PRIVATE_ROOT:
        import sys

        print(f"fdigen: warning: shared C library cache not used ({reason}); compiling "
              "into a private temporary folder", file=sys.stderr)
        _PRIVATE_ROOT.append(Path(tempfile.mkdtemp(prefix="fdigen-c-private-")))
    return _PRIVATE_ROOT[0]


def state_fields(real, nz: int, nr: int, window: int, startup: int = 0) -> list:
    """The ctypes fields of the generated ``<prefix>_state`` struct (``fdi.h.j2``;
    ``elapsed`` only with a start-up, ``[fdi] startup``)."""
    i32, u32 = ctypes.c_int32, ctypes.c_uint32
    return [("z", real * nz), ("buf", real * nr * window), ("index", i32),
            ("sums", real * nr), ("flags", u32), ("candidate", i32), ("count", i32),
            ("decision", i32), ("initialised", i32), ("frozen", i32), ("late", u32),
            ("action_candidate", i32), ("action_count", i32), ("action", i32)] + (
                [("elapsed", i32)] if startup else [])


def _design_key(design: FdiDesign, float_type: str, cc: str) -> str:
    """Identity of a design's rendered C: the model hash and fdigen's code and templates."""
    from fdigen.design.cache import _code_digest
    from fdigen.backends.render import TEMPLATES_DIR

    h = hashlib.sha256()
    h.update(model_hash(design.model).encode())
    h.update(_code_digest().encode())
    for path in sorted(TEMPLATES_DIR.rglob("*.j2")):
        h.update(path.read_bytes())
    h.update(repr((float_type, cc, SHARED_FLAGS, design.evaluation.thresholds.tolist(),
                   design.evaluation.patterns, design.evaluation.confirm,
                   design.evaluation.window, design.evaluation.actions,
                   design.evaluation.horizons, design.evaluation.ambiguity,
                   design.evaluation.class_flags, design.evaluation.escalate,
                   design.evaluation.ambiguity_samples)).encode())
    h.update(str(design.step.assignments).encode())
    h.update(str(design.step.outputs).encode())
    h.update(str(design.init.outputs).encode())
    return h.hexdigest()[:32]


def _library_for(design, prefix, float_type, cc, cache_dir) -> Path:
    """The shared library of a design, rendering and compiling only on a cache miss."""
    root = Path(cache_dir) if cache_dir is not None else _cache_root()
    index = root / "index" / _design_key(design, float_type, cc)
    if index.is_file():
        path = Path(index.read_text().strip())
        if path.is_file():
            return path
    model = design.model
    sources = render_c_sources(design, float_type=float_type,
                               model_source=Path(model.source).name,
                               model_hash=model_hash(model))
    path = build_shared_library(sources, prefix, cc=cc, cache_dir=cache_dir)
    index.parent.mkdir(parents=True, exist_ok=True)
    tmp = index.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(str(path))
    os.replace(tmp, index)
    return path


def build_shared_library(sources: dict[str, str], library: str, *, cc: str = "gcc",
                         cache_dir: str | Path | None = None) -> Path:
    """Compile generated sources into a shared library, cached by content.

    Parameters
    ----------
    sources : dict of str to str
        File name -> text; every ``.c`` file except ``main.c`` is compiled.
    library : str
        Base name of the library (``lib<library>.so``).
    cc : str
        The C compiler.
    cache_dir : str or Path, optional
        Where built libraries are kept; default: a per-user folder in the temp directory.

    Returns
    -------
    Path
        The shared library (reused if these sources were built before).

    Raises
    ------
    RuntimeError
        If compilation fails (the compiler's output is in the message).
    """
    c_files = sorted(n for n in sources if n.endswith(".c") and n != "main.c")
    key = hashlib.sha256(repr((sorted(sources.items()), cc, SHARED_FLAGS)).encode()).hexdigest()
    root = Path(cache_dir) if cache_dir is not None else _cache_root()
    target = root / key[:24] / f"lib{library}.so"
    if target.is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        for name, text in sources.items():
            (Path(tmp) / name).write_text(text)
        out = Path(tmp) / target.name
        cmd = [cc, *SHARED_FLAGS, "-o", str(out), *c_files, "-lm"]
        proc = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr}")
        os.replace(out, target)
    return target


def _array(a, dtype, shape=None, name="array"):
    arr = np.ascontiguousarray(a, dtype=dtype)
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    return arr


class CFdi:
    """The generated C FDI, compiled and loaded with ctypes.

    Parameters
    ----------
    design : FdiDesign
    parameters : dict of str to float, optional
        Overrides of the model's parameter values (checked by the generated ``init``).
    float_type : {"double", "float"}
    cc : str
        The C compiler used to build the shared library.
    cache_dir : str or Path, optional
        Where the built library is cached (see :func:`build_shared_library`).

    Raises
    ------
    ValueError
        On an unknown parameter name, or a value the generated ``init`` rejects.
    """

    def __init__(self, design: FdiDesign, parameters: dict | None = None,
                 float_type: str = "double", cc: str = "gcc", cache_dir=None):
        if float_type not in _CTYPES:
            raise ValueError(f"float_type must be one of {sorted(_CTYPES)}, got {float_type!r}")
        self.design = design
        model = design.model
        self.real, self.dtype = _CTYPES[float_type]
        self.prefix = f"{model.name}_fdi"
        self.library_path = _library_for(design, self.prefix, float_type, cc, cache_dir)
        self.lib = ctypes.CDLL(str(self.library_path))
        self.nz, self.nu, self.ny = len(design.state_names), len(model.inputs), len(model.outputs)
        self.nr, self.naux = len(design.residual_names), len(design.aux_names)
        self._declare()

        values = {q.name: q.value for q in model.parameters}
        unknown = set(parameters or {}) - set(values)
        if unknown:
            raise ValueError(f"unknown parameter(s) {sorted(unknown)}")
        values.update(parameters or {})
        self.p = np.array([values[q.name] for q in model.parameters], dtype=self.dtype)
        self.params = self._Params(*self.p)
        self.state = self._State()
        status = self._fn("init")(ctypes.byref(self.state), ctypes.byref(self.params))
        if status != 0:
            index = -100 - status
            if 0 <= index < len(model.parameters):
                q = model.parameters[index]
                raise ValueError(f"parameter {q.name} = {values[q.name]!r} rejected by "
                                 f"{self.prefix}_init (bounds {q.bounds}, must be finite)")
            raise ValueError(f"{self.prefix}_init failed with status {status}")

    # -- ctypes declarations ----------------------------------------------------------------
    def _fn(self, name):
        return getattr(self.lib, f"{self.prefix}_{name}")

    def _declare(self):
        real, d = self.real, lambda n: max(n, 1)
        nr, window = d(self.nr), self.design.evaluation.window
        fields = [(q.name, real) for q in self.design.model.parameters]
        self._Params = type("Params", (ctypes.Structure,), {"_fields_": fields})
        self._State = type("State", (ctypes.Structure,), {
            "_fields_": state_fields(real, d(self.nz), nr, window,
                                     self.design.evaluation.startup)})
        self._Output = type("Output", (ctypes.Structure,), {"_fields_": [
            ("r", real * nr), ("rms", real * nr), ("flags", ctypes.c_uint32),
            ("fault_class", ctypes.c_int32), ("action", ctypes.c_int32),
            ("aux", real * d(self.naux)), ("faults", ctypes.c_uint32)]})
        rp, ip, vp = ctypes.POINTER(real), ctypes.POINTER(ctypes.c_int32), ctypes.c_void_p
        for name, args in {"init": [vp, vp], "reset": [vp], "step": [vp, vp, rp, rp, vp],
                           "core": [rp] * 8,
                           "run": [vp, vp, ctypes.c_long, rp, rp, rp, rp, ip, ip, ip, rp, ip]}.items():
            fn = self._fn(name)
            fn.argtypes, fn.restype = args, ctypes.c_int

    def _ptr(self, arr):
        return arr.ctypes.data_as(ctypes.POINTER(self.real))

    def _check(self, status, what):
        if status < 0:
            raise RuntimeError(f"{self.prefix}_{what} failed with status {status}")
        return status

    # -- the ReferenceFdi interface ---------------------------------------------------------
    def reset(self):
        """Forget the FDI state; the next step initialises it from its sample."""
        self._check(self._fn("reset")(ctypes.byref(self.state)), "reset")

    def core(self, z, u, y, mode):
        """The generated residual generator only: ``(z_next, r, aux)``.

        Parameters
        ----------
        z, u, y : array_like
            FDI state, inputs and measured outputs.
        mode : array_like
            ``(freeze, accommodate)``.

        Returns
        -------
        tuple of numpy.ndarray
            ``z_next``, ``r``, ``aux`` as float64.
        """
        dt = self.dtype
        args = [_array(z, dt, (self.nz,), "z"), _array(u, dt, (self.nu,), "u"),
                _array(y, dt, (self.ny,), "y"), self.p, _array(mode, dt, (2,), "mode")]
        outs = [np.zeros(max(n, 1), dtype=dt) for n in (self.nz, self.nr, self.naux)]
        self._check(self._fn("core")(*(self._ptr(a) for a in args + outs)), "core")
        return tuple(o[:n].astype(np.float64) for o, n in zip(outs, (self.nz, self.nr, self.naux)))

    def core_run(self, z0, u, y, freeze_from: int) -> np.ndarray:
        """The generated residual generator over a whole log, its state carried from
        sample to sample: ``r[k]`` of ``z[k+1], r[k], _ = core(z[k], u[k], y[k],
        (k >= freeze_from, 0))`` from ``z[0] = z0`` (no evaluation: the realignment
        frozen from ``freeze_from`` on, whatever the flags). Returns ``r`` (K, n_r).

        The same C function as :meth:`core`, called once per sample on buffers converted
        once (a per-sample :meth:`core` converts its arguments every call: 100 us a sample
        from Python, where this loop costs a few).
        """
        dt = self.dtype
        u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
        K = u.shape[0] if u.ndim == 2 else -1
        if u.ndim != 2 or y.ndim != 2 or u.shape != (K, self.nu) or y.shape != (K, self.ny) \
                or K < 1:
            raise ValueError(f"u must be (K, {self.nu}) and y (K, {self.ny}) with K >= 1, "
                             f"got {u.shape} and {y.shape}")
        u, y = np.ascontiguousarray(u, dtype=dt), np.ascontiguousarray(y, dtype=dt)
        zs = [np.zeros(max(self.nz, 1), dtype=dt), np.zeros(max(self.nz, 1), dtype=dt)]
        zs[0][:self.nz] = _array(z0, dt, (self.nz,), "z")
        r = np.zeros((K, max(self.nr, 1)), dtype=dt)
        aux = np.zeros(max(self.naux, 1), dtype=dt)
        modes = np.array([[0.0, 0.0], [1.0, 0.0]], dtype=dt)
        # the same symbol with untyped pointers: addresses are passed as plain integers
        fn = self.lib[f"{self.prefix}_core"]
        fn.argtypes, fn.restype = [ctypes.c_void_p] * 8, ctypes.c_int
        zp = [a.ctypes.data for a in zs]
        u0, y0, r0 = u.ctypes.data, y.ctypes.data, r.ctypes.data
        ub, yb, rb = u.strides[0], y.strides[0], r.strides[0]
        p, a = self.p.ctypes.data, aux.ctypes.data
        m0, m1 = modes[0].ctypes.data, modes[1].ctypes.data
        for k in range(K):
            status = fn(zp[k & 1], u0 + k * ub, y0 + k * yb, p, m1 if k >= freeze_from else m0,
                        zp[1 - (k & 1)], r0 + k * rb, a)
            if status < 0:
                self._check(status, "core")
        return r[:, :self.nr].astype(np.float64)

    def step(self, u, y) -> dict:
        """One FDI step on one sample; a dict like ``ReferenceFdi.step``."""
        out = self._Output()
        u = _array(u, self.dtype, (self.nu,), "u")
        y = _array(y, self.dtype, (self.ny,), "y")
        #: the status of the last step (0 OK, 1 _WARN_NONFINITE, 2 _WARN_STATE)
        self.last_status = self._check(self._fn("step")(
            ctypes.byref(self.state), ctypes.byref(self.params), self._ptr(u), self._ptr(y),
            ctypes.byref(out)), "step")
        return {"r": np.array(out.r[:self.nr], dtype=float),
                "rms": np.array(out.rms[:self.nr], dtype=float), "flags": int(out.flags),
                "fault_class": int(out.fault_class), "action": int(out.action),
                "aux": np.array(out.aux[:self.naux], dtype=float), "faults": int(out.faults)}

    #: The outputs of :meth:`run`, in the order of the C ``_run``'s arguments.
    RUN_OUTPUTS = ("r", "rms", "flags", "fault_class", "action", "aux", "faults")

    def run(self, u: np.ndarray, y: np.ndarray, outputs=None) -> dict:
        """Run the generated step over a whole log from a reset, in one C call.

        Parameters
        ----------
        u : numpy.ndarray
            Inputs, shape ``(K, n_u)``.
        y : numpy.ndarray
            Measured outputs, shape ``(K, n_y)``.
        outputs : iterable of str, optional
            The outputs wanted (of :attr:`RUN_OUTPUTS`); default all. The C ``_run`` is
            given NULL for the others, which are then neither written nor allocated.

        Returns
        -------
        dict
            ``r``, ``rms`` (K, n_r) and ``aux`` (K, n_aux) float64; ``flags``,
            ``fault_class``, ``action`` (K,) int64 -- as ``ReferenceFdi.run`` (only the
            keys asked for). The arrays the C wrote are returned without a copy where
            their type is already the one promised (``double`` builds).

        Raises
        ------
        ValueError
            On an unknown output name or a bad shape.
        """
        wanted = self.RUN_OUTPUTS if outputs is None else tuple(outputs)
        unknown = set(wanted) - set(self.RUN_OUTPUTS)
        if unknown:
            raise ValueError(f"unknown output(s) {sorted(unknown)}; "
                             f"choose from {self.RUN_OUTPUTS}")
        K = int(np.shape(u)[0])
        u = _array(u, self.dtype, (K, self.nu), "u")
        y = _array(y, self.dtype, (K, self.ny), "y")
        shapes = {"r": (K, self.nr), "rms": (K, self.nr), "aux": (K, self.naux)}
        arrays = {}
        for name in self.RUN_OUTPUTS:
            if name in wanted:
                arrays[name] = (np.empty(shapes[name], dtype=self.dtype) if name in shapes
                                else np.empty(K, dtype=np.int32))
        ip = ctypes.POINTER(ctypes.c_int32)

        def pointer(name):
            if name not in arrays:
                return None
            return (self._ptr(arrays[name]) if name in shapes
                    else arrays[name].ctypes.data_as(ip))

        self.reset()
        self._check(self._fn("run")(
            ctypes.byref(self.state), ctypes.byref(self.params), K, self._ptr(u), self._ptr(y),
            *(pointer(n) for n in self.RUN_OUTPUTS)), "run")
        return {name: arr.astype(np.float64 if name in shapes else np.int64, copy=False)
                for name, arr in arrays.items()}
