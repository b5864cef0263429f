"""The FDI step over samples: the full step with its window buffer, a whole log, and the
fixed blocks and chunks :class:`~fdigen.backends.casadi_backend.runner.CasadiFdi` runs.

* :func:`step_function`: the whole FDI step of :class:`fdigen.backends.reference.ReferenceFdi`
  (initialisation on the first sample, mode from the latched flags and decision, core,
  moving RMS, latched flags, isolation) as a pure function of an *extended state* vector.
* :func:`whole_log_function`: ``step_function(design).mapaccum(K)``, a log of ``K``
  samples in one call.
* :func:`block_function` and :func:`chunk_function` chain the step kernel
  (:func:`~fdigen.backends.casadi_backend.step_kernel.step_kernel_function`) over a fixed
  number of samples (at most one window), the runner supplying the squares that leave the
  window from the residual history and chaining chunks through the small kernel state.

The extended state is one column vector;
:func:`~fdigen.backends.casadi_backend.functions.state_layout` gives its slices. The moving
RMS window is a shift register (oldest sample first): each sample computes
``sums = (sums + sq) - oldest``, drops the oldest block and appends ``sq``. The reference
keeps an indexed ring buffer instead; both subtract the square that entered ``N`` samples
earlier (zero during the first ``N`` samples), with the same association, so the running
sums are bitwise identical.
"""

from __future__ import annotations

import casadi as ca

from fdigen.backends.casadi_backend.convert import literal_sx
from fdigen.backends.casadi_backend.functions import STEP_OUTPUTS, state_layout
from fdigen.backends.casadi_backend.step_kernel import KERNEL_BLOCKS, step_kernel_function
from fdigen.design.fdi_design import FdiDesign


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
        The result of
        :func:`~fdigen.backends.casadi_backend.functions.core_function` (built if not given).
    kernel : casadi.Function, optional
        The result of
        :func:`~fdigen.backends.casadi_backend.step_kernel.step_kernel_function` (built from ``core`` if not given).
    pure_sx : bool, default False
        ``False``: an MX function calling the SX :func:`step_kernel_function` and
        shifting the ``N*n_r`` buffer with two block copies (compiles in about a second,
        copies with ``memcpy``-like loops). ``True``: the kernel inlined into one SX
        function whose buffer shift is ``N*n_r`` scalar assignments (the same arithmetic,
        bit for bit, but slow to compile).

    Returns
    -------
    casadi.Function
        ``state`` is laid out as
        :func:`~fdigen.backends.casadi_backend.functions.state_layout`; the all-zero vector is the reset
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
        The result of
        :func:`~fdigen.backends.casadi_backend.step_kernel.step_kernel_function` (built if not given).
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
