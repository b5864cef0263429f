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
* :func:`step_kernel_function`: the step without the window buffer (the squares leaving
  the window are an input); :func:`block_function` and :func:`chunk_function` chain it
  over a fixed number of samples (at most one window), the runner supplying the squares
  that leave the window from the residual history and chaining chunks through the small
  kernel state.

The extended state is one column vector; :func:`state_layout` gives its slices. The moving
RMS window is a shift register (oldest sample first): each sample computes
``sums = (sums + sq) - oldest``, drops the oldest block and appends ``sq``. The reference
keeps an indexed ring buffer instead; both subtract the square that entered ``N`` samples
earlier (zero during the first ``N`` samples), with the same association, so the running
sums are bitwise identical.

Every SX graph is built with CasADi's on-the-fly simplification off
(:func:`~fdigen.backends.casadi_backend.convert.literal_sx`), so that the arithmetic is the
reference's, operation for operation.
"""

from __future__ import annotations

import casadi as ca

from fdigen.backends.casadi_backend.convert import literal_sx, sympy_to_casadi
from fdigen.design.config import ACTIONS
from fdigen.design.evaluation import HORIZON_NONE
from fdigen.design.fdi_design import FdiDesign
from fdigen.design.program import Program
from fdigen.model.model import Model

#: Names of the extended-state blocks, in order.
STATE_BLOCKS = ("z", "buffer", "sums", "flags", "candidate", "count", "decision",
                "initialised", "frozen", "late", "action_candidate", "action_count", "action")
#: Output names of :func:`step_function`.
STEP_OUTPUTS = ("state_next", "r", "rms", "flags", "fault_class", "action", "aux", "faults")


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
        0/1), ``candidate``, ``count``, ``decision``, ``initialised``, ``frozen`` (one
        entry each), ``late`` (``n_r`` latched bits as 0/1), ``action_candidate``,
        ``action_count``, ``action`` (one entry each), and ``"size"``: ``slice(0, n)`` with ``n`` the total length.
    """
    nz, nr, N = len(design.state_names), len(design.residual_names), design.evaluation.window
    sizes = {"z": nz, "buffer": N * nr, "sums": nr, "flags": nr, "candidate": 1, "count": 1,
             "decision": 1, "initialised": 1, "frozen": 1, "late": nr,
             "action_candidate": 1, "action_count": 1, "action": 1}
    out, start = {}, 0
    for name in STATE_BLOCKS:
        out[name] = slice(start, start + sizes[name])
        start += sizes[name]
    out["size"] = slice(0, start)
    return out


def _lookup(index, table, default=0.0):
    """``table[index]`` for an SX integer index (exact if_else chain)."""
    acc = ca.SX(float(default))
    for k, value in enumerate(table):
        if value != default:
            acc = ca.if_else(index == k, float(value), acc)
    return acc


def _isolation(ev, flags):
    """The candidate class, as :meth:`ReferenceFdi.evaluate
    <fdigen.backends.reference.ReferenceFdi.evaluate>`: with flags up, the class of the
    patterns ``(S, class)`` consistent with them (``F & ~S == 0``: no raised flag outside
    the signature), in pattern order; 0 when none is, or when two classes are. Also
    whether any pattern is consistent, and the most and least severe action code of the
    consistent patterns' classes.

    Returns
    -------
    (SX, SX, SX, SX)
        ``match, hit, amax, amin``.
    """
    match, ambiguous = ca.SX(0.0), ca.SX(0.0)
    hit, amax, amin = ca.SX(0.0), ca.SX(0.0), ca.SX(float(len(ACTIONS)))
    any_flag = ca.SX(0.0)
    for b in flags:
        any_flag = ca.logic_or(any_flag, b != 0)
    for pattern, cls in ev.patterns:
        outside = [flags[i] for i in range(len(flags)) if not (pattern >> i) & 1]
        consistent = any_flag
        for b in outside:
            consistent = ca.logic_and(consistent, b == 0)
        a = float(ev.action_codes[cls])
        hit = ca.if_else(consistent, 1.0, hit)
        amax = ca.if_else(ca.logic_and(consistent, a > amax), a, amax)
        amin = ca.if_else(ca.logic_and(consistent, a < amin), a, amin)
        ambiguous = ca.if_else(ca.logic_and(consistent, ca.logic_and(match != 0,
                                                                      match != cls)),
                               1.0, ambiguous)
        match = ca.if_else(ca.logic_and(consistent, match == 0), float(cls), match)
    return ca.if_else(ca.logic_and(any_flag, ambiguous == 0), match, 0.0), hit, amax, amin


def _consistent_faults(ev, flags):
    """The consistent-fault mask as :meth:`Evaluation.consistent_faults
    <fdigen.design.evaluation.Evaluation.consistent_faults>` (a double, exact below 2^53)."""
    any_flag = ca.SX(0.0)
    for b in flags:
        any_flag = ca.logic_or(any_flag, b != 0)
    mask = ca.SX(0.0)
    for k, sig in enumerate(ev.fault_masks):
        consistent = any_flag
        for i in range(len(flags)):
            if not (sig >> i) & 1:
                consistent = ca.logic_and(consistent, flags[i] == 0)
        mask = mask + ca.if_else(consistent, float(1 << k), 0.0)
    return mask


#: The blocks of the extended state the step kernel reads and writes (all but the buffer).
KERNEL_BLOCKS = tuple(b for b in STATE_BLOCKS if b != "buffer")
#: Input and output names of :func:`step_kernel_function`, :func:`block_function` and
#: :func:`chunk_function`: the step's, with ``oldest`` and ``sq`` last.
KERNEL_INPUTS = ("small", "u", "y", "p", "oldest")
KERNEL_OUTPUTS = ("small_next",) + STEP_OUTPUTS[1:] + ("sq",)


def kernel_layout(design: FdiDesign) -> dict:
    """Slices of the kernel state ``small`` (the extended state without the buffer).

    Parameters
    ----------
    design : FdiDesign

    Returns
    -------
    dict of str to slice
        One slice per block of :data:`KERNEL_BLOCKS`, and ``"size"``.
    """
    lay = state_layout(design)
    out, start = {}, 0
    for name in KERNEL_BLOCKS:
        size = lay[name].stop - lay[name].start
        out[name] = slice(start, start + size)
        start += size
    out["size"] = slice(0, start)
    return out


def chunk_geometry(design: FdiDesign) -> tuple[int, int]:
    """Samples per block and blocks per chunk of :func:`chunk_function`.

    A chunk is at most one window long (``N`` samples), so that every square leaving the
    window during a chunk entered it in an earlier chunk: the runner supplies them from
    the residual history and the recursion carries only the running sums.

    Returns
    -------
    (int, int)
        ``(B, blocks)``: ``B = min(BLOCK, N)``, ``blocks = max(1, min(BLOCKS, N // B))``.
    """
    N = int(design.evaluation.window)
    B = max(1, min(BLOCK, N))
    return B, max(1, min(BLOCKS, N // B))


def step_kernel_function(design: FdiDesign, core: ca.Function | None = None) -> ca.Function:
    """The FDI step without the window buffer: one SX function.

    ``<m>_step_kernel(small, u, y, p, oldest) -> (small_next, r, rms, flags, fault_class,
    action, aux, sq)``, where ``small`` is the extended state without the buffer (the
    blocks of :data:`KERNEL_BLOCKS`, in order; :func:`kernel_layout`), ``oldest`` the
    squared residuals leaving the window (those that entered it ``N`` samples earlier,
    zero during the first ``N`` samples) and ``sq`` the squares entering it.
    :func:`step_function` wraps it with the shift of the buffer; :func:`block_function`
    and :func:`chunk_function` chain it over samples with ``oldest`` supplied from outside.

    Parameters
    ----------
    design : FdiDesign
    core : casadi.Function, optional
        The result of :func:`core_function` (built if not given).

    Returns
    -------
    casadi.Function
    """
    with literal_sx():   # calling ``core`` on SX re-builds its nodes: keep them literal
        return _kernel(design, core_function(design) if core is None else core)


def _kernel(design, core):
    ev = design.evaluation
    lay = state_layout(design)
    nr, N = len(ev.residuals), ev.window
    sizes = {b: lay[b].stop - lay[b].start for b in KERNEL_BLOCKS}
    small = ca.SX.sym("small", sum(sizes.values()))
    oldest = ca.SX.sym("oldest", nr)
    u = ca.SX.sym("u", len(design.step.inputs["u"]))
    y = ca.SX.sym("y", len(design.step.inputs["y"]))
    p = ca.SX.sym("p", len(design.step.inputs["p"]))
    part, start = {}, 0
    for b in KERNEL_BLOCKS:
        part[b] = small[start:start + sizes[b]]
        start += sizes[b]
    sums, flags = _scalars(part["sums"]), _scalars(part["flags"])
    cand, count, dec, initialised, frozen = (part[b][0] for b in (
        "candidate", "count", "decision", "initialised", "frozen"))
    late = _scalars(part["late"])

    # 1. initialisation from the first sample
    z0 = convert_program(design.init, {"u": u, "y": y, "p": p})["z0"]
    z = ca.if_else(initialised != 0, part["z"], z0)

    # 2. mode from the previous flags / decision
    any_flag = ca.SX(0.0)
    for b in flags:
        any_flag = ca.logic_or(any_flag, b != 0)
    freeze = ca.if_else(any_flag, 1.0, 0.0)
    accommodate = ca.if_else(part["action"][0] == 1, 1.0, 0.0)

    # 3. core
    z_next, r, aux = core(z, u, y, p, ca.vertcat(freeze, accommodate))

    # 4. moving RMS, latched flags
    # a non-finite (or huge) square enters the window as 0 and reads as an infinite RMS
    # (see Evaluation): NaN never hides a fault
    sq_raw = [v * v for v in _scalars(r)]
    ok = [s <= ev.sq_max for s in sq_raw]
    sq = [ca.if_else(ok[i], sq_raw[i], 0.0) for i in range(nr)]
    olds = _scalars(oldest)
    # state validation (Evaluation.state_valid): a corrupted residual reads an infinite RMS
    counters_ok = ca.logic_and(ca.logic_and(count >= 0.0, frozen >= 0.0),
                               part["action_count"][0] >= 0.0)
    valid = [ca.logic_and(ca.logic_and(counters_ok, ca.logic_and(
        sums[i] >= ev.sum_min, sums[i] <= ev.sum_max)), ca.logic_and(
        olds[i] >= 0.0, olds[i] <= ev.sq_max)) for i in range(nr)]
    new_sums = [(sums[i] + sq[i]) - olds[i] for i in range(nr)]
    rms = [ca.if_else(ca.logic_and(ok[i], valid[i]),
                      ca.sqrt(ca.if_else(sv > 0.0, sv, 0.0) * (1.0 / N)), ca.inf)
           for i, sv in enumerate(new_sums)]
    new_flags = [ca.if_else(ca.logic_or(flags[i] != 0, rms[i] > float(ev.thresholds[i])),
                            1.0, 0.0) for i in range(nr)]
    mask = ca.SX(0.0)
    for i, b in enumerate(new_flags):
        mask = mask + b * float(1 << i)

    # 5. late flags: risen after their horizon of samples run frozen (Evaluation)
    new_frozen = ca.if_else(ca.logic_and(any_flag, frozen < float(HORIZON_NONE)),
                            frozen + 1.0, frozen)
    new_late = [ca.if_else(ca.logic_or(late[i] != 0, ca.logic_and(
        ca.logic_and(new_flags[i] != 0, flags[i] == 0), new_frozen > float(ev.horizons[i]))),
        1.0, 0.0) for i in range(nr)]

    # 6. isolation: the class of the fault signatures consistent with the evidence (the
    #    flags without the late ones), class-level part
    evidence = [ca.if_else(new_late[i] != 0, 0.0, b) for i, b in enumerate(new_flags)]
    cflags = [b if ev.class_flags >> i & 1 else ca.SX(0.0) for i, b in enumerate(evidence)]
    match, hit, amax, amin = _isolation(ev, cflags)
    matched = match != 0
    new_count = ca.if_else(ca.logic_and(matched, match == cand), count + 1.0,
                           ca.if_else(matched, 1.0, 0.0))
    # 7. the action the consistent classes call for (ambiguity policy), and its count
    acand = ca.if_else(ca.logic_and(hit != 0, ca.logic_or(float(ev.most_severe) != 0,
                                                          amin == amax)), amax, 0.0)
    new_acount = ca.if_else(ca.logic_and(acand != 0, acand == part["action_candidate"][0]),
                            part["action_count"][0] + ca.if_else(
                                part["action_count"][0] < float(HORIZON_NONE), 1.0, 0.0),
                            ca.if_else(acand != 0, 1.0, 0.0))
    # 8. contradiction: a flag outside the isolated class's signatures, or none explains
    any_c = ca.SX(0.0)
    outside = ca.SX(0.0)
    for i, b in enumerate(cflags):
        any_c = ca.logic_or(any_c, b != 0)
        inside = _lookup(dec, [u >> i & 1 for u in ev.class_unions])
        if ev.escalate:
            outside = ca.logic_or(outside, ca.logic_and(b != 0, inside == 0))
    contradicted = ca.if_else(dec == 0, ca.logic_and(any_c, hit == 0), outside)
    confirmed = ca.logic_and(ca.logic_and(dec == 0, matched), new_count >= float(ev.confirm))
    new_dec = ca.if_else(contradicted, float(ev.unexplained),
                         ca.if_else(confirmed, match, dec))
    need = ca.if_else(amin == amax, float(ev.confirm), float(ev.ambiguity_samples))
    taken = ca.if_else(ca.logic_and(new_dec == 0, new_acount >= need), acand, 0.0)
    act = _lookup(new_dec, ev.action_codes)
    act = ca.if_else(taken > act, taken, act)
    action = part["action"][0]
    action = ca.if_else(act > action, act, action)

    small_next = ca.vertcat(z_next, _vec(new_sums), _vec(new_flags), match, new_count,
                            new_dec, ca.SX(1.0), new_frozen, _vec(new_late), acand,
                            new_acount, action)
    return ca.Function(f"{design.name}_step_kernel", [small, u, y, p, oldest],
                       [small_next, r, _vec(rms), mask, new_dec, action, aux,
                        _consistent_faults(ev, evidence), _vec(sq)],
                       list(KERNEL_INPUTS), list(KERNEL_OUTPUTS))


def step_function(design: FdiDesign, core: ca.Function | None = None, *,
                  pure_sx: bool = False, kernel: ca.Function | None = None) -> ca.Function:
    """The complete FDI step as a pure function of an extended state.

    ``<m>_step(state, u, y, p) -> (state_next, r, rms, flags, fault_class, action, aux,
    faults)``,
    operation for operation :meth:`ReferenceFdi.step
    <fdigen.backends.reference.ReferenceFdi.step>`:

    1. ``z = initialised ? z : init(u, y, p)`` (the first sample initialises);
    2. mode from the previous flags and decision: ``freeze = (flags != 0)``,
       ``accommodate = (action_code[decision] == 1)``;
    3. ``z_next, r, aux = core(z, u, y, p, mode)``;
    4. ``sq = r*r <= Q_max ? r*r : 0``, ``sums = (sums + sq) - oldest`` (shift register,
       see module doc), ``rms = r*r <= Q_max ? sqrt((sums > 0 ? sums : 0) * (1/N)) : inf``,
       ``flag_i |= rms_i > J_i`` (:class:`~fdigen.design.evaluation.Evaluation`);
    5. with flags up, the class of the patterns ``(S, class)`` of
       ``design.evaluation.patterns`` consistent with the flag mask ``F``
       (``F & ~S == 0``) is the candidate, none when two classes are; its consecutive
       count; the decision latches once the count reaches ``confirm``; ``faults``, the
       mask of the declared faults consistent with the flags.

    Parameters
    ----------
    design : FdiDesign
    core : casadi.Function, optional
        The result of :func:`core_function` (built if not given).
    kernel : casadi.Function, optional
        The result of :func:`step_kernel_function` (built from ``core`` if not given).
    pure_sx : bool, default False
        ``False``: an MX function calling the SX :func:`step_kernel_function` and
        shifting the ``N*n_r`` buffer with two block copies (compiles in about a second,
        copies with ``memcpy``-like loops). ``True``: the kernel inlined into one SX
        function whose buffer shift is ``N*n_r`` scalar assignments (the same arithmetic,
        bit for bit, but slow to compile).

    Returns
    -------
    casadi.Function
        ``state`` is laid out as :func:`state_layout`; the all-zero vector is the reset
        state. ``flags`` is the mask as a double, ``fault_class`` the latched class
        index, ``action`` its action code.
    """
    lay = state_layout(design)
    nr = len(design.residual_names)
    kernel = step_kernel_function(design, core) if kernel is None else kernel
    sym = ca.SX.sym if pure_sx else ca.MX.sym
    s = sym("state", lay["size"].stop)
    u = sym("u", kernel.size1_in(1))
    y = sym("y", kernel.size1_in(2))
    p = sym("p", kernel.size1_in(3))
    buf = s[lay["buffer"]]
    small = ca.vertcat(*[s[lay[b]] for b in KERNEL_BLOCKS])
    with literal_sx():
        out = kernel(small, u, y, p, buf[0:nr])
        small_next, sq = out[0], out[8]
        nz = lay["z"].stop
        s_next = ca.vertcat(small_next[0:nz], buf[nr:], sq, small_next[nz:])
        return ca.Function(f"{design.name}_step", [s, u, y, p], [s_next] + list(out[1:8]),
                           ["state", "u", "y", "p"], list(STEP_OUTPUTS))


def whole_log_function(design: FdiDesign, K: int, *, step: ca.Function | None = None,
                       final_state_only: bool = False, base: int | None = None,
                       name: str | None = None) -> ca.Function:
    """``step_function(design).mapaccum(K)``: ``K`` samples in one call.

    Parameters
    ----------
    design : FdiDesign
    K : int
        Number of samples.
    step : casadi.Function, optional
        The result of :func:`step_function` (built if not given).
    final_state_only : bool, default False
        Return only the state after the last sample instead of the whole state
        trajectory (``N*n_r`` doubles per sample).
    base : int, optional
        CasADi's ``mapaccum`` option: unrolled steps per level of its tower of loops;
        ``-1`` unrolls completely. Default: ``-1`` up to 64 samples, CasADi's default
        (10) above, which takes seconds to build for this large a state: for long logs
        prefer :func:`chunk_function` chained through the state.
    name : str, optional
        Function name, default ``<m>_log``.

    Returns
    -------
    casadi.Function
        ``<m>_log(state[n], u[m x K], y[p x K], p[q]) -> (state_next[n x K], r[n_r x K],
        rms[n_r x K], flags[1 x K], fault_class[1 x K], action[1 x K], aux[n_a x K])``;
        column ``k`` of ``state_next`` is the state after sample ``k`` (one column with
        ``final_state_only``). ``p`` may be given as one column (it is repeated).
    """
    K = int(K)
    if K < 1:
        raise ValueError("K must be a positive number of samples")
    step = step_function(design) if step is None else step
    if base is None:
        base = -1 if K <= 64 else 10
    F = step.mapaccum(f"{design.name}_mapaccum{K}", K, 1, {"base": int(base)})
    return _wrapped(F, name or f"{design.name}_log", final_state_only)


def _wrapped(F: ca.Function, name: str, final_state_only: bool) -> ca.Function:
    """``F`` under a stable name (CasADi may name a mapaccum after its inner tower),
    optionally keeping only the last column of its first output."""
    ins = [ca.MX.sym(F.name_in(i), F.sparsity_in(i)) for i in range(F.n_in())]
    out = F(*ins)
    out = [out] if F.n_out() == 1 else list(out)
    if final_state_only:
        out[0] = out[0][:, out[0].size2() - 1]
    return ca.Function(name, ins, out, F.name_in(), F.name_out())


#: Largest samples per block of :func:`block_function` and blocks per chunk of
#: :func:`chunk_function` (see :func:`chunk_geometry`: a chunk never exceeds the window).
BLOCK = 32
BLOCKS = 32


def block_function(design: FdiDesign, *, kernel: ca.Function | None = None,
                   length: int | None = None) -> ca.Function:
    """``length`` samples of the step kernel, unrolled, returning the final state only.

    ``kernel.mapaccum(length)`` (``base=-1``) under the name ``<m>_block``: the recursion
    carries the kernel state ``small`` (no window buffer); the squares leaving the window
    come in as ``oldest``, one column per sample.

    Parameters
    ----------
    design : FdiDesign
    kernel : casadi.Function, optional
        The result of :func:`step_kernel_function` (built if not given).
    length : int, optional
        Default: the block length of :func:`chunk_geometry`.

    Returns
    -------
    casadi.Function
        ``<m>_block(small[s], u[m x B], y[p x B], p[q], oldest[n_r x B]) ->
        (small_next[s], r[n_r x B], rms, flags, fault_class, action, aux, sq[n_r x B])``.
    """
    kernel = step_kernel_function(design) if kernel is None else kernel
    length = chunk_geometry(design)[0] if length is None else int(length)
    F = kernel.mapaccum(f"{design.name}_kernel_mapaccum{length}", length, 1, {"base": -1})
    return _wrapped(F, f"{design.name}_block", True)


def chunk_function(design: FdiDesign, *, block: ca.Function | None = None,
                   blocks: int | None = None) -> ca.Function:
    """A fixed-length log chunk, ``blocks`` blocks of :func:`block_function`.

    Two nested mapaccums (``block.mapaccum(blocks)`` over the kernel's ``mapaccum(B)``)
    returning the final kernel state only. A chunk is at most one window long
    (:func:`chunk_geometry`): the runner supplies ``oldest`` for every sample from the
    squares of earlier chunks, and the state copied from sample to sample is the kernel
    state (``n_z + 2 n_r + 4`` doubles), not the ``N x n_r`` window.

    Parameters
    ----------
    design : FdiDesign
    block : casadi.Function, optional
        The result of :func:`block_function` (built if not given).
    blocks : int, optional
        Default: the blocks per chunk of :func:`chunk_geometry`.

    Returns
    -------
    casadi.Function
        ``<m>_chunk(small[s], u[m x L], y[p x L], p[q], oldest[n_r x L]) ->
        (small_next[s], r[n_r x L], rms, flags, fault_class, action, aux, sq[n_r x L])``
        with ``L = blocks * block length``.
    """
    block = block_function(design) if block is None else block
    blocks = chunk_geometry(design)[1] if blocks is None else int(blocks)
    outer = block.mapaccum(f"{design.name}_blocks", blocks, 1, {"base": -1})
    return _wrapped(outer, f"{design.name}_chunk", True)
