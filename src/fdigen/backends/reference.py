"""The reference backend: the FDI design evaluated directly from its sympy expressions.

This is the ground truth every generated backend is checked against. The step program is
turned into one numpy function by :func:`sympy.lambdify`, whose common-subexpression hook
receives the program's own assignments (so nothing is re-derived). Residual evaluation and
isolation (:class:`fdigen.design.evaluation.Evaluation`) are written out here in plain
Python, operation for operation as the templates emit them.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from dataclasses import dataclass

import numpy as np
import sympy as sp
from sympy.printing.numpy import NumPyPrinter
from sympy.printing.precedence import PRECEDENCE

from fdigen.design.config import ACTIONS
from fdigen.design.evaluation import HORIZON_NONE, late_mask
from fdigen.design.fdi_design import FdiDesign
from fdigen.design.program import Program
from fdigen.safe_lambdify import safe_lambdify


class _ExactPowPrinter(NumPyPrinter):
    """numpy printer writing ``x**2`` as ``x*x`` and ``x**-1`` as ``1/x``.

    numpy *scalars* evaluate ``x**2`` through the C library's ``pow``, which is not always
    correctly rounded; the compiled backends multiply. Printing the product keeps the
    reference exact and every backend bit-comparable.
    """

    def _print_Pow(self, expr, rational=False):
        if expr.exp == 2:
            base = self.parenthesize(expr.base, PRECEDENCE["Mul"])
            return f"({base}*{base})"
        if expr.exp == -1:
            return f"(1.0/{self.parenthesize(expr.base, PRECEDENCE['Mul'])})"
        return super()._print_Pow(expr, rational=rational)


#: sympy function -> C library name of the transcendental functions the reference takes
#: from the C library, as the compiled backends do: numpy's SIMD kernels (AVX-512) differ
#: from it in the last place for tanh, exp, log, sinh... (sqrt is correctly rounded both
#: ways and stays numpy's).
_LIBM_FUNCTIONS = {sp.tanh: "tanh", sp.sinh: "sinh", sp.cosh: "cosh", sp.exp: "exp",
                   sp.log: "log", sp.sin: "sin", sp.cos: "cos", sp.tan: "tan",
                   sp.asin: "asin", sp.acos: "acos", sp.atan: "atan", sp.atan2: "atan2"}


def _libm_namespace() -> dict:
    """``{"libm_<name>": function}``: each C library function, elementwise over arrays.

    Empty (numpy's own kernels are used) where no C math library can be loaded.
    """
    path = ctypes.util.find_library("m")
    try:
        lib = ctypes.CDLL(path)
    except OSError:
        return {}
    out = {}
    for name in _LIBM_FUNCTIONS.values():
        cfun = getattr(lib, name)
        nargs = 2 if name == "atan2" else 1
        cfun.restype = ctypes.c_double
        cfun.argtypes = [ctypes.c_double] * nargs
        vec = np.vectorize(cfun, otypes=[float])

        def call(*args, _c=cfun, _v=vec):
            try:
                return _c(*args)          # Python floats and numpy float64 scalars
            except ctypes.ArgumentError:  # arrays
                return _v(*args)

        out[f"libm_{name}"] = call
    return out


def lambdify_program(program: Program, output_names: list[str]):
    """A numpy function ``f(*input_vectors) -> list of output vectors`` for a program.

    Inputs are passed as one sequence per named input vector, in ``program.inputs`` order.
    Every expression is evaluated elementwise, so each scalar may be a numpy array (many
    points at once).
    """
    args = [list(vec) for vec in program.inputs.values()]
    outs = [list(program.outputs[name]) for name in output_names]
    assignments = list(program.assignments)

    def own_cse(exprs):
        return assignments, exprs

    libm = _libm_namespace()
    user = {f.__name__: f"libm_{name}" for f, name in _LIBM_FUNCTIONS.items()
            if f"libm_{name}" in libm}
    printer = _ExactPowPrinter({"fully_qualified_modules": False, "inline": True,
                                "allow_unknown_functions": True, "user_functions": user})
    return safe_lambdify(args, outs, modules=[libm, "numpy"], cse=own_cse, printer=printer)


@dataclass
class EvaluationState:
    """The residual-evaluation part of the FDI state (ring buffers, flags, decision)."""

    buffer: np.ndarray       # (N, n_res) squared residuals
    index: int
    sums: np.ndarray         # running sums of squares
    flags: int               # latched flag mask
    candidate: int           # class matching the flags now (0: none)
    count: int               # consecutive samples the candidate has matched
    decision: int            # latched isolated class (0: none)
    frozen: int = 0          # samples run with the realignment frozen (saturating)
    late: int = 0            # flags that rose after their horizon (latched mask)
    action_candidate: int = 0  # action the consistent classes call for now (0: none)
    action_count: int = 0    # consecutive samples the action candidate has held
    action: int = 0          # latched action code (never decreases)
    elapsed: int = 0         # samples since the start, saturating at the start-up's


class ReferenceFdi:
    """One FDI core evaluated from the symbolic design.

    Parameters
    ----------
    design : FdiDesign
    parameters : dict of str to float, optional
        Overrides of the model's parameter values.
    """

    def __init__(self, design: FdiDesign, parameters: dict | None = None):
        self.design = design
        self.ev = design.evaluation
        values = {q.name: q.value for q in design.model.parameters}
        values.update(parameters or {})
        self.p = np.array([values[q.name] for q in design.model.parameters], dtype=float)
        self.step_fn = lambdify_program(design.step, ["z_next", "r", "aux"])
        self.init_fn = lambdify_program(design.init, ["z0"])
        self.reset()

    def reset(self):
        n_res = len(self.ev.residuals)
        self.z = None
        self.state = EvaluationState(np.zeros((self.ev.window, n_res)), 0, np.zeros(n_res),
                                     0, 0, 0, 0)
        self.state_corrupt = False   # the last step found a corrupted state (C: _WARN_STATE)

    def initialise(self, u0, y0):
        """FDI state from the first sample (the generated ``init``)."""
        (z0,) = self.init_fn(list(u0), list(y0), list(self.p))
        self.z = np.array(z0, dtype=float)

    def mode(self) -> tuple[float, float]:
        """(freeze, accommodate): realignment frozen once any flag is up; accommodation
        once the isolated class's action is ``accommodate``."""
        freeze = 1.0 if self.state.flags else 0.0
        acc = 1.0 if self.state.action == 1 else 0.0
        return freeze, acc

    def core(self, z, u, y, mode):
        """The symbolic step only: ``(z_next, r, aux)`` for given state and inputs.

        numpy's warnings are off: a select evaluates both of its branches, and the branch
        it discards may be NaN by design (a prediction outside the equations' domain,
        held; a sensor's reading out of range, replaced)."""
        with np.errstate(all="ignore"):
            zn, r, aux = self.step_fn(list(z), list(u), list(y), list(self.p), list(mode))
        return np.array(zn, dtype=float), np.array(r, dtype=float), np.array(aux, dtype=float)

    def evaluate(self, r) -> np.ndarray:
        """Moving RMS (eq 22), latched flags and isolation for one sample; returns RMS."""
        ev, st = self.ev, self.state
        N = ev.window
        inv_n = 1.0 / N          # the RMS scales by the reciprocal, as every backend does
        rms = np.empty(len(r))
        old_flags = st.flags
        # state validation (Evaluation.state_valid): a corrupted residual reads inf
        all_flags = (1 << len(r)) - 1
        counters_ok = (st.count >= 0 and st.frozen >= 0 and st.action_count >= 0
                       and st.flags & ~all_flags == 0
                       and st.late & ~all_flags == 0
                       and 0 <= st.elapsed <= ev.startup)
        valid = ev.state_valid(counters_ok, st.sums, st.buffer[st.index])
        self.state_corrupt = not all(valid)
        st.frozen += 1 if old_flags and st.frozen < HORIZON_NONE else 0
        # start-up: no flag rises before it ends (a corrupted counter: at once)
        started = st.elapsed >= ev.startup or not counters_ok
        st.elapsed += 1 if st.elapsed < ev.startup else 0
        for i, value in enumerate(r):
            sq = value * value
            ok = sq <= ev.sq_max            # False for NaN, infinity, huge
            sq_in = sq if ok else 0.0
            st.sums[i] = st.sums[i] + sq_in - st.buffer[st.index, i]
            st.buffer[st.index, i] = sq_in
            s = st.sums[i] if st.sums[i] > 0.0 else 0.0
            rms[i] = np.sqrt(s * inv_n) if ok and valid[i] else np.inf
            if rms[i] > ev.thresholds[i] and started:
                st.flags |= 1 << i
        st.index = st.index + 1 if st.index + 1 < N else 0
        st.late |= st.flags & ~old_flags & late_mask(ev.horizons, st.frozen)
        # the evidence: the flags without the late ones; the class reads its class level
        class_flags = st.flags & ~st.late & ev.class_flags
        match, ambiguous, hit = 0, 0, 0
        amax, amin = 0, len(ACTIONS)
        if class_flags:
            for mask, cls in ev.patterns:
                if class_flags & ~mask == 0:
                    hit = 1
                    amax = max(amax, ev.action_codes[cls])
                    amin = min(amin, ev.action_codes[cls])
                    if match == 0:
                        match = cls
                    elif match != cls:
                        ambiguous = 1
        if ambiguous:
            match = 0
        if match != 0 and match == st.candidate:
            st.count += 1
        else:
            st.count = 1 if match != 0 else 0
        st.candidate = match
        # the action the consistent classes call for (ambiguity policy), and its count
        acand = amax if hit and (ev.most_severe or amin == amax) else 0
        if acand != 0 and acand == st.action_candidate:
            st.action_count += 1 if st.action_count < HORIZON_NONE else 0
        else:
            st.action_count = 1 if acand != 0 else 0
        st.action_candidate = acand
        # contradiction: a flag the isolated class cannot explain, or none explains them
        if st.decision == 0:
            contradicted = class_flags != 0 and not hit
        else:
            contradicted = ev.escalate and class_flags & ~ev.class_unions[st.decision] != 0
        if contradicted:
            st.decision = ev.unexplained
        elif st.decision == 0 and match != 0 and st.count >= ev.confirm:
            st.decision = match
        need = ev.confirm if amin == amax else ev.ambiguity_samples
        taken = acand if st.decision == 0 and st.action_count >= need else 0
        st.action = max(st.action, ev.action_codes[st.decision], taken)
        return rms

    def step(self, u, y):
        """One FDI step on one sample; returns a dict of this sample's outputs."""
        if self.z is None:
            self.initialise(u, y)
        mode = self.mode()
        self.z, r, aux = self.core(self.z, u, y, mode)
        rms = self.evaluate(r)
        st = self.state
        return {"r": r, "rms": rms, "flags": st.flags, "fault_class": st.decision,
                "action": st.action, "aux": aux,
                "faults": self.ev.consistent_faults(st.flags & ~st.late)}

    def run(self, u: np.ndarray, y: np.ndarray) -> dict:
        """Run the step over a whole log (``u``: (K, m), ``y``: (K, p)) from a reset."""
        self.reset()
        K = u.shape[0]
        n_res = len(self.ev.residuals)
        out = {"r": np.empty((K, n_res)), "rms": np.empty((K, n_res)),
               "flags": np.empty(K, dtype=np.int64), "fault_class": np.empty(K, dtype=np.int64),
               "action": np.empty(K, dtype=np.int64),
               "aux": np.empty((K, len(self.design.aux_names))),
               "faults": np.empty(K, dtype=np.int64)}
        for k in range(K):
            res = self.step(u[k], y[k])
            for key in out:
                out[key][k] = res[key]
        return out
