"""The FDI step without the window buffer, as one CasADi SX function.

:func:`step_kernel_function` is the step of :class:`fdigen.backends.reference.ReferenceFdi`
(initialisation, mode, core, moving RMS, latched flags, frozen horizons, isolation and the
action policy) on the *kernel state* (the extended state of
:func:`~fdigen.backends.casadi_backend.functions.state_layout` without its window buffer):
the squares leaving the window come in as ``oldest`` and those entering it go out as
``sq``. :mod:`.log_functions` wraps it with the buffer and chains it over samples.
"""

from __future__ import annotations

import casadi as ca

from fdigen.backends.casadi_backend.convert import literal_sx
from fdigen.backends.casadi_backend.functions import (STATE_BLOCKS, STEP_OUTPUTS,
                                                      convert_program, core_function,
                                                      state_layout, sx_scalars, sx_vector)
from fdigen.design.config import ACTIONS
from fdigen.design.evaluation import HORIZON_NONE
from fdigen.design.fdi_design import FdiDesign


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
#: Input and output names of :func:`step_kernel_function` and of
#: :func:`~fdigen.backends.casadi_backend.log_functions.block_function` and
#: :func:`~fdigen.backends.casadi_backend.log_functions.chunk_function`: the step's, with ``oldest`` and ``sq`` last.
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



def step_kernel_function(design: FdiDesign, core: ca.Function | None = None) -> ca.Function:
    """The FDI step without the window buffer: one SX function.

    ``<m>_step_kernel(small, u, y, p, oldest) -> (small_next, r, rms, flags, fault_class,
    action, aux, sq)``, where ``small`` is the extended state without the buffer (the
    blocks of :data:`KERNEL_BLOCKS`, in order; :func:`kernel_layout`), ``oldest`` the
    squared residuals leaving the window (those that entered it ``N`` samples earlier,
    zero during the first ``N`` samples) and ``sq`` the squares entering it.
    :func:`~fdigen.backends.casadi_backend.log_functions.step_function` wraps it with the shift of the buffer; :mod:`.log_functions`'
    ``block_function`` and ``chunk_function`` chain it over samples with ``oldest`` supplied from outside.

    Parameters
    ----------
    design : FdiDesign
    core : casadi.Function, optional
        The result of
        :func:`~fdigen.backends.casadi_backend.functions.core_function` (built if not given).

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
    sums, flags = sx_scalars(part["sums"]), sx_scalars(part["flags"])
    cand, count, dec, initialised, frozen = (part[b][0] for b in (
        "candidate", "count", "decision", "initialised", "frozen"))
    late = sx_scalars(part["late"])

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
    sq_raw = [v * v for v in sx_scalars(r)]
    ok = [s <= ev.sq_max for s in sq_raw]
    sq = [ca.if_else(ok[i], sq_raw[i], 0.0) for i in range(nr)]
    olds = sx_scalars(oldest)
    # state validation (Evaluation.state_valid): a corrupted residual reads an infinite RMS
    counters_ok = ca.logic_and(ca.logic_and(count >= 0.0, frozen >= 0.0),
                               part["action_count"][0] >= 0.0)
    # start-up ([fdi] startup): no flag rises before its S samples (a corrupted counter:
    # at once); the count saturates
    S = float(ev.startup)
    started, new_elapsed = ca.SX(1.0), []
    if ev.startup:
        elapsed = part["elapsed"][0]
        counters_ok = ca.logic_and(counters_ok, ca.logic_and(elapsed >= 0.0, elapsed <= S))
        started = ca.logic_or(elapsed >= S, ca.logic_not(counters_ok))
        new_elapsed = [ca.if_else(elapsed < S, elapsed + 1.0, elapsed)]
    valid = [ca.logic_and(ca.logic_and(counters_ok, ca.logic_and(
        sums[i] >= ev.sum_min, sums[i] <= ev.sum_max)), ca.logic_and(
        olds[i] >= 0.0, olds[i] <= ev.sq_max)) for i in range(nr)]
    new_sums = [(sums[i] + sq[i]) - olds[i] for i in range(nr)]
    rms = [ca.if_else(ca.logic_and(ok[i], valid[i]),
                      ca.sqrt(ca.if_else(sv > 0.0, sv, 0.0) * (1.0 / N)), ca.inf)
           for i, sv in enumerate(new_sums)]
    new_flags = [ca.if_else(ca.logic_or(flags[i] != 0, ca.logic_and(
        rms[i] > float(ev.thresholds[i]), started) if ev.startup else
        rms[i] > float(ev.thresholds[i])), 1.0, 0.0) for i in range(nr)]
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

    small_next = ca.vertcat(z_next, sx_vector(new_sums), sx_vector(new_flags), match, new_count,
                            new_dec, ca.SX(1.0), new_frozen, sx_vector(new_late), acand,
                            new_acount, action, *new_elapsed)
    return ca.Function(f"{design.name}_step_kernel", [small, u, y, p, oldest],
                       [small_next, r, sx_vector(rms), mask, new_dec, action, aux,
                        _consistent_faults(ev, evidence), sx_vector(sq)],
                       list(KERNEL_INPUTS), list(KERNEL_OUTPUTS))
