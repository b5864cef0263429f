"""CasADi functions of the FDI design: model, core step, full step, whole-log evaluation.

* :func:`model_functions`: the plant ``f(x,u,p)``, its Jacobians ``A``, ``B``, the outputs
  ``h(x,u,p)`` and ``C`` (CasADi algorithmic differentiation).
* :func:`core_function`: the design's step program, ``(z,u,y,p,mode) -> (z_next,r,aux)``,
  built assignment by assignment (each assignment one SX, shared by everything after it).
* :func:`step_function`: the whole FDI step of :class:`fdigen.backends.reference.ReferenceFdi`
  (initialisation on the first sample, mode from the latched flags and decision, core,
  moving RMS, latched flags, isolation) as a pure function of an *extended state* vector.
* :func:`whole_log_function`: ``step_function(design).mapaccum(K)``, a log of ``K``
  samples in one call.

The extended state is one column vector; :func:`state_layout` gives its slices. The moving
RMS window is a shift register (oldest sample first): each sample computes
``sums = (sums + sq) - oldest``, drops the oldest block and appends ``sq``. The reference
keeps an indexed ring buffer instead; both subtract the square that entered ``N`` samples
earlier (zero during the first ``N`` samples), with the same association, so the running
sums are bitwise identical.
"""

from __future__ import annotations

import casadi as ca

from fdigen.backends.casadi_backend.convert import literal_sx, sympy_to_casadi
from fdigen.design.fdi_design import FdiDesign
from fdigen.design.program import Program
from fdigen.model.model import Model

#: Names of the extended-state blocks, in order.
STATE_BLOCKS = ("z", "buffer", "sums", "flags", "candidate", "count", "decision",
                "initialised")
#: Output names of :func:`step_function`.
STEP_OUTPUTS = ("state_next", "r", "rms", "flags", "fault_class", "action", "aux")


def _vec(items) -> ca.SX:
    items = list(items)
    return ca.vertcat(*items) if items else ca.SX(0, 1)


def _scalars(v: ca.SX) -> list:
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
        mapping.update(zip(syms, _scalars(vec)))
    memo = {}
    for sym, expr in program.assignments:
        mapping[sym] = sympy_to_casadi(expr, mapping, memo=memo)
    return {name: _vec(sympy_to_casadi(e, mapping, memo=memo) for e in vec)
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
    mapping = dict(zip(list(model.x), _scalars(x)))
    mapping.update(zip(list(model.u), _scalars(u)))
    mapping.update(zip(list(model.p), _scalars(p)))
    memo = {}
    with literal_sx():
        f = _vec(sympy_to_casadi(e, mapping, memo=memo) for e in model.f())
        h = _vec(sympy_to_casadi(e, mapping, memo=memo) for e in model.h())
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
    """Slices of the extended state vector of :func:`step_function`.

    Parameters
    ----------
    design : FdiDesign

    Returns
    -------
    dict of str to slice
        ``z`` (FDI core state), ``buffer`` (``N*n_r`` squared residuals, oldest sample
        first, sample-major), ``sums`` (``n_r``), ``flags`` (``n_r`` latched bits as
        0/1), ``candidate``, ``count``, ``decision``, ``initialised`` (one entry each),
        and ``"size"``: ``slice(0, n)`` with ``n`` the total length.
    """
    nz, nr, N = len(design.state_names), len(design.residual_names), design.evaluation.window
    sizes = {"z": nz, "buffer": N * nr, "sums": nr, "flags": nr, "candidate": 1, "count": 1,
             "decision": 1, "initialised": 1}
    out, start = {}, 0
    for name in STATE_BLOCKS:
        out[name] = slice(start, start + sizes[name])
        start += sizes[name]
    out["size"] = slice(0, start)
    return out


def _lookup(index: ca.SX, table, default=0.0) -> ca.SX:
    """``table[index]`` for an SX integer index (exact if_else chain)."""
    acc = ca.SX(float(default))
    for k, value in enumerate(table):
        if value != default:
            acc = ca.if_else(index == k, float(value), acc)
    return acc


def step_function(design: FdiDesign, core: ca.Function | None = None) -> ca.Function:
    """The complete FDI step as a pure function of an extended state.

    ``<m>_step(state, u, y, p) -> (state_next, r, rms, flags, fault_class, action, aux)``,
    operation for operation :meth:`ReferenceFdi.step
    <fdigen.backends.reference.ReferenceFdi.step>`:

    1. ``z = initialised ? z : init(u, y, p)`` (the first sample initialises);
    2. mode from the previous flags and decision: ``freeze = (flags != 0)``,
       ``accommodate = (action_code[decision] == 1)``;
    3. ``z_next, r, aux = core(z, u, y, p, mode)``;
    4. ``sq = r*r``, ``sums = (sums + sq) - oldest`` (shift register, see module doc),
       ``rms = sqrt((sums > 0 ? sums : 0) / N)``, ``flag_i |= rms_i > J_i``;
    5. the last pattern of ``design.evaluation.patterns`` equal to the flag mask gives the
       candidate class; its consecutive count; the decision latches once the count
       reaches ``confirm``.

    Parameters
    ----------
    design : FdiDesign
    core : casadi.Function, optional
        The result of :func:`core_function` (built if not given).

    Returns
    -------
    casadi.Function
        An SX function. ``state`` is laid out as :func:`state_layout`; the all-zero
        vector is the reset state. ``flags`` is the mask as a double, ``fault_class`` the
        latched class index, ``action`` its action code.
    """
    with literal_sx():   # calling ``core`` on SX re-builds its nodes: keep them literal
        return _step_function(design, core)


def _step_function(design, core):
    ev = design.evaluation
    lay = state_layout(design)
    nr, N = len(ev.residuals), ev.window
    core = core_function(design) if core is None else core
    s = ca.SX.sym("state", lay["size"].stop)
    u = ca.SX.sym("u", len(design.step.inputs["u"]))
    y = ca.SX.sym("y", len(design.step.inputs["y"]))
    p = ca.SX.sym("p", len(design.step.inputs["p"]))
    z_prev = s[lay["z"]]
    buf = s[lay["buffer"]]
    sums = _scalars(s[lay["sums"]])
    flags = _scalars(s[lay["flags"]])
    cand, count, dec, initialised = (s[lay[k].start] for k in
                                     ("candidate", "count", "decision", "initialised"))

    # 1. initialisation from the first sample
    z0 = convert_program(design.init, {"u": u, "y": y, "p": p})["z0"]
    z = ca.if_else(initialised != 0, z_prev, z0)

    # 2. mode from the previous flags / decision
    any_flag = ca.SX(0.0)
    for b in flags:
        any_flag = ca.logic_or(any_flag, b != 0)
    freeze = ca.if_else(any_flag, 1.0, 0.0)
    accommodate = ca.if_else(_lookup(dec, ev.action_codes) == 1, 1.0, 0.0)

    # 3. core
    z_next, r, aux = core(z, u, y, p, ca.vertcat(freeze, accommodate))

    # 4. moving RMS, latched flags
    rs = _scalars(r)
    sq = [v * v for v in rs]
    oldest = _scalars(buf[0:nr])
    new_sums = [(sums[i] + sq[i]) - oldest[i] for i in range(nr)]
    new_buf = ca.vertcat(buf[nr:], _vec(sq))
    rms = [ca.sqrt(ca.if_else(sv > 0.0, sv, 0.0) / N) for sv in new_sums]
    new_flags = [ca.if_else(ca.logic_or(flags[i] != 0, rms[i] > float(ev.thresholds[i])),
                            1.0, 0.0) for i in range(nr)]
    mask = ca.SX(0.0)
    for i, b in enumerate(new_flags):
        mask = mask + b * float(1 << i)

    # 5. isolation
    match = ca.SX(0.0)
    for pattern, cls in ev.patterns:
        match = ca.if_else(mask == float(pattern), float(cls), match)
    matched = match != 0
    new_count = ca.if_else(ca.logic_and(matched, match == cand), count + 1.0,
                           ca.if_else(matched, 1.0, 0.0))
    confirmed = ca.logic_and(ca.logic_and(dec == 0, matched), new_count >= float(ev.confirm))
    new_dec = ca.if_else(confirmed, match, dec)
    action = _lookup(new_dec, ev.action_codes)

    s_next = ca.vertcat(z_next, new_buf, _vec(new_sums), _vec(new_flags), match, new_count,
                        new_dec, ca.SX(1.0))
    return ca.Function(f"{design.name}_step", [s, u, y, p],
                       [s_next, r, _vec(rms), mask, new_dec, action, aux],
                       ["state", "u", "y", "p"], list(STEP_OUTPUTS))


def whole_log_function(design: FdiDesign, K: int, step: ca.Function | None = None
                       ) -> ca.Function:
    """``step_function(design).mapaccum(K)``: ``K`` samples in one call.

    Parameters
    ----------
    design : FdiDesign
    K : int
        Number of samples.
    step : casadi.Function, optional
        The result of :func:`step_function` (built if not given).

    Returns
    -------
    casadi.Function
        ``<m>_log(state[n], u[m x K], y[p x K], p[q]) -> (state_next[n x K], r[n_r x K],
        rms[n_r x K], flags[1 x K], fault_class[1 x K], action[1 x K], aux[n_a x K])``;
        column ``k`` of ``state_next`` is the state after sample ``k``. ``p`` may be given
        as one column (it is repeated).
    """
    if int(K) < 1:
        raise ValueError("K must be a positive number of samples")
    step = step_function(design) if step is None else step
    return step.mapaccum(f"{design.name}_log", int(K))
