"""The FDI design run through CasADi: interpreted SX/MX functions or the compiled library.

:class:`CasadiFdi` has the interface of :class:`fdigen.backends.reference.ReferenceFdi`
(``core``, ``step``, ``run``, ``reset``) and the same results. ``run`` evaluates a log in
fixed chunks of :data:`~fdigen.backends.casadi_backend.functions.BLOCK` x
:data:`~fdigen.backends.casadi_backend.functions.BLOCKS` samples chained through the
extended state, so that one function (compiled once) serves every log length.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from fdigen.backends.casadi_backend.compiled import build_functions, compiled_functions
from fdigen.backends.casadi_backend.functions import state_layout
from fdigen.design.fdi_design import FdiDesign


class CasadiFdi:
    """One FDI core evaluated by CasADi.

    Parameters
    ----------
    design : FdiDesign
    parameters : dict of str to float, optional
        Overrides of the model's parameter values.
    compiled : bool, default False
        ``False``: CasADi's virtual machine evaluates the symbolic functions.
        ``True``: the functions of the compiled library
        (:func:`~fdigen.backends.casadi_backend.compiled.compiled_functions`), compiled
        once into ``cache_dir``.
    cache_dir : str or Path, optional
        Library cache folder (default ``$FDIGEN_CACHE`` or ``~/.cache/fdigen``).

    Attributes
    ----------
    functions : dict of str to casadi.Function
        ``core``, ``step``, ``block``, ``chunk`` and the model functions ``f A B h C``
        (keys of :func:`~fdigen.backends.casadi_backend.compiled.function_names`).
    chunk_length : int
        Samples per call of the chunk function.
    state : numpy.ndarray
        The extended state (layout :func:`~fdigen.backends.casadi_backend.functions.
        state_layout`) after the last sample of :meth:`step` or :meth:`run`.
    """

    def __init__(self, design: FdiDesign, parameters: dict | None = None,
                 compiled: bool = False, *, cache_dir=None):
        self.design = design
        self.ev = design.evaluation
        self.compiled = bool(compiled)
        values = {q.name: q.value for q in design.model.parameters}
        values.update(parameters or {})
        self.p = np.array([values[q.name] for q in design.model.parameters], dtype=float)
        symbolic = build_functions(design)
        self.functions = (compiled_functions(design, cache_dir, functions=symbolic)
                          if self.compiled else symbolic)
        self.layout = state_layout(design)
        self.chunk_length = int(self.functions["chunk"].size2_in(1))
        self.reset()

    def reset(self):
        """Back to the state before the first sample (all zero, not initialised)."""
        self._state = np.zeros(self.layout["size"].stop)
        self._pending = None

    @property
    def state(self) -> np.ndarray:
        """The extended state after the last sample processed."""
        if self._pending is not None:
            self._state = _dense(self._advance(*self._pending))
            self._pending = None
        return self._state

    @state.setter
    def state(self, value):
        self._state = np.asarray(value, dtype=float).reshape(-1).copy()
        self._pending = None

    def core(self, z, u, y, mode):
        """The symbolic step only: ``(z_next, r, aux)`` for given state and inputs.

        Parameters
        ----------
        z, u, y, mode : array_like
            One vector each (``mode`` is ``(freeze, accommodate)``). Many points at once:
            give any of them as ``(length, npoints)`` arrays (columns are points; the
            others are repeated), as the reference accepts arrays per entry.

        Returns
        -------
        tuple of numpy.ndarray
            ``z_next``, ``r``, ``aux``: 1-D for one point, ``(length, npoints)`` else.
        """
        args = [np.asarray(a, dtype=float) for a in (z, u, y, mode)]
        many = any(a.ndim > 1 for a in args)
        args = [a.reshape(a.shape[0], -1) if a.ndim > 1 else a.reshape(-1, 1) for a in args]
        npts = max(a.shape[1] for a in args)
        args = [np.broadcast_to(a, (a.shape[0], npts)) if a.shape[1] == 1 else a
                for a in args]
        z_, u_, y_, m_ = args
        res = tuple(_dense(o, 2) for o in self.functions["core"](z_, u_, y_, self.p, m_))
        return res if many else tuple(r[:, 0] for r in res)

    def step(self, u, y) -> dict:
        """One FDI step on one sample; returns a dict of this sample's outputs."""
        out = self.functions["step"](self.state, np.asarray(u, dtype=float),
                                     np.asarray(y, dtype=float), self.p)
        self.state = _dense(out[0])
        flags, cls, action = (int(round(float(o))) for o in out[3:6])
        return {"r": _dense(out[1]), "rms": _dense(out[2]), "flags": flags,
                "fault_class": cls, "action": action, "aux": _dense(out[6])}

    def run(self, u: np.ndarray, y: np.ndarray) -> dict:
        """Run the step over a whole log (``u``: (K, m), ``y``: (K, p)) from a reset.

        Returns
        -------
        dict
            As :meth:`ReferenceFdi.run <fdigen.backends.reference.ReferenceFdi.run>`:
            ``r``, ``rms`` (K, n_r) floats; ``flags``, ``fault_class``, ``action`` (K,)
            int64; ``aux`` (K, n_a) floats. :attr:`state` then holds the final state.
        """
        self.reset()
        u = np.asarray(u, dtype=float)
        y = np.asarray(y, dtype=float)
        u = u[:, None] if u.ndim == 1 else u
        y = y[:, None] if y.ndim == 1 else y
        K = u.shape[0]
        core = self.functions["core"]
        if y.shape[0] != K:
            raise ValueError(f"u has {K} samples but y has {y.shape[0]}")
        if u.shape[1] != core.size1_in(1) or y.shape[1] != core.size1_in(2):
            raise ValueError(f"u must be (K, {core.size1_in(1)}) and y (K, "
                             f"{core.size1_in(2)}), got {u.shape} and {y.shape}")
        L = self.chunk_length
        chunk = self.functions["chunk"]
        keys = ("r", "rms", "flags", "fault_class", "action", "aux")
        parts = {k: [] for k in keys}
        state = ca.DM(self._state)
        full = K - K % L
        for start in range(0, K, L):
            n = min(L, K - start)
            uc, yc = u[start:start + n].T, y[start:start + n].T
            if n < L:   # pad the last chunk with its last sample; the padding is dropped
                uc = np.pad(uc, ((0, 0), (0, L - n)), mode="edge")
                yc = np.pad(yc, ((0, 0), (0, L - n)), mode="edge")
            out = chunk(state, uc, yc, self.p)
            if n == L:
                state = out[0]
            for key, o in zip(keys, out[1:]):
                parts[key].append(_dense(o, 2)[:, :n])
        if full < K:   # the padded chunk's final state is not the log's: computed on demand
            self._pending = (state, u[full:], y[full:])
        else:
            self.state = _dense(state)
        rows = {"r": len(self.ev.residuals), "rms": len(self.ev.residuals),
                "aux": len(self.design.aux_names)}
        res = {}
        for key in keys:
            cols = (np.concatenate(parts[key], axis=1) if parts[key]
                    else np.empty((rows.get(key, 1), 0)))
            if key in rows:
                res[key] = cols.T.copy()
            else:
                res[key] = np.rint(cols[0]).astype(np.int64)
        return res

    def _advance(self, state, u, y):
        """The state after the samples ``u``, ``y`` from ``state``: whole blocks, then
        single steps."""
        block, step = self.functions["block"], self.functions["step"]
        B = int(block.size2_in(1))
        k, K = 0, u.shape[0]
        while K - k >= B:
            state = block(state, u[k:k + B].T, y[k:k + B].T, self.p)[0]
            k += B
        while k < K:
            state = step(state, u[k], y[k], self.p)[0]
            k += 1
        return state


def _dense(value, ndim: int = 1) -> np.ndarray:
    """A casadi DM (or array) as a float array, 1-D (flattened) or 2-D."""
    arr = np.array(value.full() if hasattr(value, "full") else value, dtype=float)
    if ndim == 1:
        return arr.reshape(-1)
    return arr if arr.ndim == 2 else arr.reshape(arr.size, 1)
