"""CasADi functions of the FDI design: the model and the core step.

* :func:`model_functions`: the plant ``f(x,u,p)``, its Jacobians ``A``, ``B``, the outputs
  ``h(x,u,p)`` and ``C`` (CasADi algorithmic differentiation).
* :func:`core_function`: the design's step program, ``(z,u,y,p,mode) -> (z_next,r,aux)``,
  built assignment by assignment (each assignment one SX, shared by everything after it).
* :func:`state_layout`: the slices of the extended state of the whole FDI step.

The step with evaluation is built on these: :mod:`.step_kernel` (the step without the
window buffer: moving RMS, latched flags, isolation) and :mod:`.log_functions` (the full
step with its buffer, a whole log, blocks and chunks of samples).

Every SX graph is built with CasADi's on-the-fly simplification off
(:func:`~fdigen.backends.casadi_backend.convert.literal_sx`), so that the arithmetic is the
reference's, operation for operation.
"""

from __future__ import annotations

import casadi as ca

from fdigen.backends.casadi_backend.convert import literal_sx, sympy_to_casadi
from fdigen.design.fdi_design import FdiDesign
from fdigen.design.program import Program
from fdigen.model.model import Model

#: Names of the extended-state blocks, in order.
STATE_BLOCKS = ("z", "buffer", "sums", "flags", "candidate", "count", "decision",
                "initialised", "frozen", "late", "action_candidate", "action_count", "action",
                "elapsed")
#: Output names of the whole step
#: (:func:`~fdigen.backends.casadi_backend.log_functions.step_function`).
STEP_OUTPUTS = ("state_next", "r", "rms", "flags", "fault_class", "action", "aux", "faults")


def sx_vector(items) -> ca.SX:
    items = list(items)
    return ca.vertcat(*items) if items else ca.SX(0, 1)


def sx_scalars(v: ca.SX) -> list:
    return [v[i] for i in range(v.numel())]


def convert_program(program: Program, inputs: dict) -> dict:
    """Evaluate a :class:`~fdigen.design.program.Program` on CasADi inputs.

    Parameters
    ----------
    program : Program
    inputs : dict of str to casadi.SX
        One column vector per named input vector of the program (``program.inputs``);
        missing names are not allowed.

    Returns
    -------
    dict of str to casadi.SX
        One column vector per named output. Assignments are converted in order, each to
        one SX that every later expression references (no sympy substitution).
    """
    mapping = {}
    for name, syms in program.inputs.items():
        vec = inputs[name]
        if vec.numel() != len(syms):
            raise ValueError(f"input '{name}' has {vec.numel()} entries, expected {len(syms)}")
        mapping.update(zip(syms, sx_scalars(vec)))
    memo = {}
    for sym, expr in program.assignments:
        mapping[sym] = sympy_to_casadi(expr, mapping, memo=memo)
    return {name: sx_vector(sympy_to_casadi(e, mapping, memo=memo) for e in vec)
            for name, vec in program.outputs.items()}


def model_functions(model: Model) -> dict:
    """CasADi functions of the plant model.

    Parameters
    ----------
    model : Model

    Returns
    -------
    dict of str to casadi.Function
        ``"f"``: ``<m>_f(x,u,p) -> xdot``; ``"A"``: ``<m>_A(x,u,p) -> df/dx``;
        ``"B"``: ``<m>_B(x,u,p) -> df/du``; ``"h"``: ``<m>_h(x,u,p) -> y``;
        ``"C"``: ``<m>_C(x,u,p) -> dh/dx``. Jacobians are dense.
    """
    x = ca.SX.sym("x", len(model.states))
    u = ca.SX.sym("u", len(model.inputs))
    p = ca.SX.sym("p", len(model.parameters))
    mapping = dict(zip(list(model.x), sx_scalars(x)))
    mapping.update(zip(list(model.u), sx_scalars(u)))
    mapping.update(zip(list(model.p), sx_scalars(p)))
    memo = {}
    with literal_sx():
        f = sx_vector(sympy_to_casadi(e, mapping, memo=memo) for e in model.f())
        h = sx_vector(sympy_to_casadi(e, mapping, memo=memo) for e in model.h())
    exprs = {"f": (f, "xdot"), "A": (ca.densify(ca.jacobian(f, x)), "A"),
             "B": (ca.densify(ca.jacobian(f, u)), "B"), "h": (h, "y"),
             "C": (ca.densify(ca.jacobian(h, x)), "C")}
    return {key: ca.Function(f"{model.name}_{key}", [x, u, p], [value], ["x", "u", "p"],
                             [out])
            for key, (value, out) in exprs.items()}


def core_function(design: FdiDesign) -> ca.Function:
    """The symbolic FDI step: ``<m>_core(z, u, y, p, mode) -> (z_next, r, aux)``.

    Parameters
    ----------
    design : FdiDesign

    Returns
    -------
    casadi.Function
        An SX function; ``mode`` is ``(freeze, accommodate)``. Equal to
        :meth:`ReferenceFdi.core <fdigen.backends.reference.ReferenceFdi.core>`.
    """
    prog = design.step
    names = ("z", "u", "y", "p", "mode")
    ins = {n: ca.SX.sym(n, len(prog.inputs[n])) for n in names}
    outs = convert_program(prog, ins)
    return ca.Function(f"{design.name}_core", [ins[n] for n in names],
                       [outs["z_next"], outs["r"], outs["aux"]], list(names),
                       ["z_next", "r", "aux"])


def state_layout(design: FdiDesign) -> dict:
    """Slices of the extended state vector of
    :func:`~fdigen.backends.casadi_backend.log_functions.step_function`.

    Parameters
    ----------
    design : FdiDesign

    Returns
    -------
    dict of str to slice
        ``z`` (FDI core state), ``buffer`` (``N*n_r`` squared residuals, oldest sample
        first, sample-major), ``sums`` (``n_r``), ``flags`` (``n_r`` latched bits as
        0/1), ``candidate``, ``count``, ``decision``, ``initialised``, ``frozen`` (one
        entry each), ``late`` (``n_r`` latched bits as 0/1), ``action_candidate``,
        ``action_count``, ``action`` (one entry each), ``elapsed`` (one entry with a
        start-up, ``[fdi] startup``, else none), and ``"size"``: ``slice(0, n)`` with
        ``n`` the total length.
    """
    nz, nr, N = len(design.state_names), len(design.residual_names), design.evaluation.window
    sizes = {"z": nz, "buffer": N * nr, "sums": nr, "flags": nr, "candidate": 1, "count": 1,
             "decision": 1, "initialised": 1, "frozen": 1, "late": nr,
             "action_candidate": 1, "action_count": 1, "action": 1,
             "elapsed": 1 if design.evaluation.startup else 0}
    out, start = {}, 0
    for name in STATE_BLOCKS:
        out[name] = slice(start, start + sizes[name])
        start += sizes[name]
    out["size"] = slice(0, start)
    return out
