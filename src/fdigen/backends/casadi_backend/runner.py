"""The FDI design run through CasADi: interpreted SX/MX functions or the compiled library.

:class:`CasadiFdi` has the interface of :class:`fdigen.backends.reference.ReferenceFdi`
(``core``, ``step``, ``run``, ``reset``) and the same results. ``run`` evaluates a log in
fixed chunks (:func:`~fdigen.backends.casadi_backend.log_functions.chunk_function`, at most
one RMS window long) chained through the small kernel state, so that one function
(compiled once) serves every log length. The moving-RMS window stays outside the
recursion: the squared residuals each chunk returns are kept, and the squares leaving the
window during the next chunk (``oldest``, those of ``N`` samples earlier) are taken from
them. The arithmetic is the step's, operation for operation.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from fdigen.backends.casadi_backend.compiled import (NativeFunction, build_functions,
                                                     compile_library, function_names,
                                                     load_functions)
from fdigen.backends.casadi_backend.functions import state_layout
from fdigen.backends.casadi_backend.step_kernel import KERNEL_BLOCKS
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
        ``core``, ``step``, ``kernel``, ``block``, ``chunk`` and the model functions
        ``f A B h C``
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
        self._native = None
        if self.compiled:
            lib = compile_library(design, cache_dir, functions=symbolic)
            self.functions = load_functions(design, lib)
            self._native = NativeFunction(lib, function_names(design)["chunk"],
                                          symbolic["chunk"], f"{design.name}_casadi")
        else:
            self.functions = symbolic
        self.layout = state_layout(design)
        self.chunk_length = int(self.functions["chunk"].size2_in(1))
        self._p_block = None        # the parameters, one row per sample of a chunk
        self.reset()

    def reset(self):
        """Back to the state before the first sample (all zero, not initialised)."""
        self._state = np.zeros(self.layout["size"].stop)
        self._pending = None

    @property
    def state(self) -> np.ndarray:
        """The extended state after the last sample processed."""
        if self._pending is not None:
            self._state = self._advance(*self._pending)
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
                "fault_class": cls, "action": action, "aux": _dense(out[6]),
                "faults": int(round(float(out[7])))}

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
        if self._native is not None:
            return self._run_native(u, y)
        L, N = self.chunk_length, int(self.ev.window)
        nr, na = len(self.ev.residuals), len(self.design.aux_names)
        chunk = self.functions["chunk"]
        rows = {"r": nr, "rms": nr, "aux": na, "sq": nr}
        out = {k: np.empty((rows.get(k, 1), K)) for k in _CHUNK_KEYS}
        small = ca.DM(self._small(self._state))
        uT, yT = np.ascontiguousarray(u.T), np.ascontiguousarray(y.T)
        oldest = np.zeros((nr, L))
        full = K - K % L
        for start in range(0, K, L):
            n = min(L, K - start)
            uc, yc = uT[:, start:start + L], yT[:, start:start + L]
            if n < L:   # pad the last chunk with its last sample; the padding is dropped
                uc = np.pad(uc, ((0, 0), (0, L - n)), mode="edge")
                yc = np.pad(yc, ((0, 0), (0, L - n)), mode="edge")
            _oldest(out["sq"], start, L, N, oldest)
            res = chunk(small, uc, yc, self.p, oldest)
            if n == L:
                small = res[0]
            for key, o in zip(_CHUNK_KEYS, res[1:]):
                out[key][:, start:start + n] = o.full()[:, :n]
        if full < K:   # the padded chunk's final state is not the log's: computed on demand
            self._pending = (small, u[full:], y[full:], out["sq"], full)
        else:
            self._state = self._extended(_dense(small), out["sq"], K)
            self._pending = None
        result = {}
        for key in _CHUNK_KEYS[:-1]:
            if key in rows:
                result[key] = out[key].T.copy()
            else:
                result[key] = np.rint(out[key][0]).astype(np.int64)
        return result

    def _run_native(self, u: np.ndarray, y: np.ndarray) -> dict:
        """:meth:`run` through the compiled chunk, called in place (:class:`NativeFunction`).

        Column-major ``rows x L`` blocks are C-order ``(L, rows)`` row ranges, so each
        chunk reads ``u``, ``y`` straight from the log (a last, partial chunk from a padded
        copy) and writes its outputs straight into the result arrays, allocated once and
        returned without a copy (the integer outputs converted in place). The squares
        entering the window go to a short history (:class:`_SquareHistory`, a few hundred
        kilobytes however long the log), from which the next chunks read the squares
        leaving it. The loop only adds addresses: no slice, no copy, no conversion per
        chunk.
        """
        K, L, N = u.shape[0], self.chunk_length, int(self.ev.window)
        nr, na = len(self.ev.residuals), len(self.design.aux_names)
        chunks = -(-K // L)
        Kp = chunks * L
        # full chunks read the log in place; only a last, partial chunk is copied (padded
        # with its last sample; the padding is dropped)
        u, y = np.ascontiguousarray(u), np.ascontiguousarray(y)
        tail_u = np.empty((L, u.shape[1]))
        tail_y = np.empty((L, y.shape[1]))
        if Kp > K:
            start = (chunks - 1) * L
            tail_u[:K - start], tail_y[:K - start] = u[start:], y[start:]
            tail_u[K - start:], tail_y[K - start:] = u[K - 1], y[K - 1]
        keys = ("r", "rms", "flags", "fault_class", "action", "aux", "faults")
        widths = {"r": nr, "rms": nr, "aux": na}
        out = {k: np.empty((Kp, widths[k]) if k in widths else Kp) for k in keys}
        # per output: the address of sample 0 and the bytes per sample (8 per column)
        outs = [(out[k].ctypes.data, 8 * widths.get(k, 1) * L) for k in keys]
        hist = _SquareHistory(nr, N, L, chunks)
        if self._p_block is None or self._p_block.shape[0] != L:
            self._p_block = np.ascontiguousarray(np.tile(self.p, (L, 1)))
        p = self._p_block.ctypes.data
        small = [self._small(self._state), np.empty(len(self._small(self._state)))]
        state = [small[0].ctypes.data, small[1].ctypes.data]
        u0, y0 = u.ctypes.data, y.ctypes.data
        ub, yb = 8 * u.shape[1] * L, 8 * y.shape[1] * L
        tails = (tail_u.ctypes.data, tail_y.ctypes.data)
        f = self._native
        for c in range(chunks):
            oldest, entering = hist.advance(c * L)
            uc, yc = (u0 + c * ub, y0 + c * yb) if (c + 1) * L <= K else tails
            f((state[c & 1], uc, yc, p, oldest),
              (state[1 - (c & 1)], *(a + c * b for a, b in outs), entering))
        # the kernel state after the last full chunk (the one a partial chunk started
        # from, else the last one's)
        last_full = small[chunks & 1] if Kp == K else small[(chunks - 1) & 1]
        full = K - K % L
        origin = max(0, (full if full < K else K) - N)
        window = hist.squares(origin, K)        # squares of samples origin ... K-1
        if full < K:   # the padded chunk's final state is not the log's: computed on demand
            self._pending = (ca.DM(last_full), u[full:], y[full:], window, full - origin)
        else:
            self._state = self._extended(last_full, window, K - origin)
            self._pending = None
        result = {}
        for key in keys:
            a = out[key][:K]                   # C-contiguous leading rows: no copy
            if key not in widths:              # integral floats -> int64, in place
                np.rint(a, out=a)
                a = _as_int64(a)
            result[key] = a
        return result

    # -- the kernel state and the window ---------------------------------------------------
    def _small(self, state: np.ndarray) -> np.ndarray:
        """The kernel state (the extended state without its window buffer)."""
        return np.concatenate([state[self.layout[b]] for b in KERNEL_BLOCKS])

    def _extended(self, small: np.ndarray, sq: np.ndarray, K: int) -> np.ndarray:
        """The extended state after ``K`` samples: kernel state and the window buffer (the
        squares of the last ``N`` samples, oldest first, zero before the first sample)."""
        lay, N = self.layout, int(self.ev.window)
        state = np.zeros(lay["size"].stop)
        start = 0
        for b in KERNEL_BLOCKS:
            size = lay[b].stop - lay[b].start
            state[lay[b]] = small[start:start + size]
            start += size
        window = np.zeros((N, sq.shape[0]))
        take = min(N, K)
        if take:
            window[N - take:] = sq[:, K - take:K].T
        state[lay["buffer"]] = window.reshape(-1)
        return state

    def _advance(self, small, u, y, sq, start):
        """The extended state after the samples ``u``, ``y`` (log samples ``start``...),
        from the kernel state ``small`` before them: whole blocks, then single steps."""
        block, kernel = self.functions["block"], self.functions["kernel"]
        B, N = int(block.size2_in(1)), int(self.ev.window)
        k, K = 0, u.shape[0]
        oldest = np.zeros((sq.shape[0], B))
        while K - k >= B:
            _oldest(sq, start + k, B, N, oldest)
            small = block(small, u[k:k + B].T, y[k:k + B].T, self.p, oldest)[0]
            k += B
        while k < K:
            _oldest(sq, start + k, 1, N, oldest[:, :1])
            small = kernel(small, u[k], y[k], self.p, oldest[:, :1])[0]
            k += 1
        return self._extended(_dense(small), sq, start + K)


class _SquareHistory:
    """The squared residuals of :meth:`CasadiFdi._run_native`, kept only as long as the
    window reads them.

    Sample ``k``'s squares are row ``k - base`` of a buffer of ``N + m L`` rows (``m``
    chunks, at most 64); rows before sample 0 are zero (nothing has left the window yet).
    When the next chunk does not fit, the last ``N`` rows move to the front (once per
    ``m`` chunks, ``N`` rows): every chunk then reads the squares leaving the window and
    writes those entering it as contiguous row ranges.
    """

    def __init__(self, nr: int, N: int, L: int, chunks: int):
        self.N, self.L = N, L
        self.buf = np.zeros((N + L * max(1, min(chunks, 64)), nr))
        self.base = -N                  # sample of row 0
        self._row = 8 * nr              # bytes per row

    def advance(self, a: int) -> tuple[int, int]:
        """Addresses of the rows the chunk of samples ``a ... a+L-1`` reads (the squares
        of samples ``a-N ...``) and writes (its own)."""
        if a + self.L - self.base > self.buf.shape[0]:
            self.buf[:self.N] = self.buf[a - self.N - self.base:a - self.base]
            self.base = a - self.N
        addr = self.buf.ctypes.data
        return (addr + (a - self.N - self.base) * self._row,
                addr + (a - self.base) * self._row)

    def squares(self, first: int, end: int) -> np.ndarray:
        """The squares of samples ``first ... end-1`` as an ``(n_r, end - first)`` view
        (``first >= max(0, end - N - L)``)."""
        return self.buf[first - self.base:end - self.base].T


def _as_int64(a: np.ndarray) -> np.ndarray:
    """``a.astype(np.int64)`` for integral floats, in a's own memory (int64 and float64
    have the same size): no second array of the log's length."""
    out = a.view(np.int64)
    np.copyto(out, a, casting="unsafe")
    return out


#: Outputs of the chunk function after the kernel state, in order.
_CHUNK_KEYS = ("r", "rms", "flags", "fault_class", "action", "aux", "faults", "sq")


def _oldest(sq: np.ndarray, start: int, length: int, N: int, out: np.ndarray) -> None:
    """Fill ``out`` (n_r x length) with the squares leaving the window at samples
    ``start ... start+length-1``: ``sq[:, k-N]``, zero for ``k < N``. Needs
    ``length <= N`` (those squares are all known before the samples run)."""
    first = start - N
    if first >= 0:
        out[:] = sq[:, first:first + length]
    else:
        skip = min(-first, length)
        out[:, :skip] = 0.0
        out[:, skip:] = sq[:, 0:length - skip]


def _dense(value, ndim: int = 1) -> np.ndarray:
    """A casadi DM (or array) as a float array, 1-D (flattened) or 2-D."""
    arr = np.array(value.full() if hasattr(value, "full") else value, dtype=float)
    if ndim == 1:
        return arr.reshape(-1)
    return arr if arr.ndim == 2 else arr.reshape(arr.size, 1)
