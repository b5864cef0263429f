"""Residual evaluation and isolation of the FDI design.

Holds :class:`Evaluation` (moving-window RMS, thresholds, latched flags, the signature
patterns and the action per fault class, identical in every backend) and
:func:`build_evaluation`, which assembles it from the configuration and the signature table.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fdigen.design.config import ACTIONS


@dataclass(frozen=True)
class Evaluation:
    """Residual evaluation and isolation, identical in every backend.

    Per sample ``k`` and residual ``i`` (eq 22 with a running sum, O(1) per sample):

    .. math::

        q_i[k] = \\begin{cases} r_i[k]^2 & r_i[k]^2 \\le Q_{max} \\\\
                                0 & \\text{otherwise (NaN, infinite, or huge)} \\end{cases}

        S_i[k] = S_i[k-1] + q_i[k] - q_i[k-N],\\quad
        \\mathrm{RMS}_i[k] = \\begin{cases} \\sqrt{\\max(S_i[k], 0)/N} &
            r_i[k]^2 \\le Q_{max} \\\\ +\\infty & \\text{otherwise} \\end{cases},\\quad
        \\mathrm{flag}_i[k] = \\mathrm{flag}_i[k-1] \\lor (\\mathrm{RMS}_i[k] > J_i)

    *Start-up* (``[fdi] startup``, :math:`S` samples): a flag rises only from the core's
    :math:`S`-th sample on, :math:`\\mathrm{flag}_i[k] = \\mathrm{flag}_i[k-1] \\lor
    (\\mathrm{RMS}_i[k] > J_i \\land k \\ge S)`, counting from 0 at the first sample and
    at every reset (a saturating count ``elapsed`` in the state); the residuals and their
    RMS run from the first sample.

    NaN never hides a fault: a residual that is not finite (or whose square exceeds
    ``Q_max = DBL_MAX / (2N)``, so that the running sum of ``N`` entries cannot overflow)
    enters the window as 0, so the sum stays finite and recovers, and reads as an infinite
    RMS, so its flag rises and stays latched. (Without this, one NaN made the sum NaN and
    the clamp ``max(S, 0)`` read it as 0 for the rest of the run: the flag could never
    rise.)

    The latched flags form a bit mask ``F``. A fault with signature mask ``S`` is
    *consistent* with the flags when every raised flag is in its signature,
    ``F & ~S == 0`` (flags rise one after another, so a signature is matched while it
    builds up). When ``F != 0`` and every consistent fault belongs to one class, that class
    is the candidate; when it stays the candidate for ``confirm`` consecutive samples it is
    isolated and latched. ``patterns`` holds ``(S, class)`` for every declared fault.

    Beside the class, every backend outputs the *consistent faults* as a bit mask
    (bit ``k`` for the ``k``-th declared fault, ``fault_masks[k]`` its signature):

    .. math:: \\Phi = \\sum_k 2^k\\,[F \\ne 0]\\,[F \\,\\&\\, \\lnot S_k = 0]

    a pure function of the latched flags, so the faults named never contradict a raised
    flag (see ``docs/isolation.md``). The class decision reads the flags of
    ``class_flags`` only (``F & class_flags`` in place of ``F``): the residuals added to
    separate faults *within* a class (to the structural isolability) refine the faults
    named and never change the class or its action.

    *Validity horizon of frozen residuals.* The realignment of the parallel models freezes
    at the first flag; a frozen parallel model drifts with the plant's tolerances, so its
    flags say less the later they rise. With ``n[k]`` the samples run frozen up to sample
    ``k`` (saturating) and ``H_i`` residual ``i``'s horizon in samples (``2^31 - 1``: none),
    a flag rising at ``k`` is *late* when ``n[k] > H_i``, latched in the mask ``L``:

    .. math:: n[k] = n[k-1] + [F[k-1] \\ne 0],\\qquad
              L[k] = L[k-1] \\lor \\sum_i 2^i\\,[F_i[k] \\land \\lnot F_i[k-1]]\\,[n[k] > H_i]

    Late flags stay in ``F`` (they are reported) but are no evidence: the class decision
    and the consistent faults both read ``E = F & ~L`` (the class decision its class-level
    part ``E_c = E & class_flags``), so the faults named and the class decided never read
    different flags.

    *An action for every state* (``[fdi] ambiguity``). With ``C`` the classes of the
    patterns consistent with ``E_c`` and ``a(c)`` the action code of class ``c`` (severity
    order ``none < accommodate < safety_stop``), the *action candidate* is

    .. math:: \\alpha = \\begin{cases} \\max_{c \\in C} a(c) & C \\ne \\emptyset \\land
              (\\text{policy} = \\text{most\\_severe} \\lor \\min_C a = \\max_C a) \\
              0 & \\text{otherwise} \\end{cases}

    held for ``confirm`` consecutive samples (``ambiguity_samples`` when the consistent
    classes' actions differ: ``[fdi] ambiguity_time``) it is taken while no class is
    isolated; the
    output action is latched and never decreases: ``A[k] = max(A[k-1], a(D[k]),
    [count_alpha >= confirm] alpha)``, with ``D`` the latched decision.

    *Contradiction escalates* (``[fdi] unexplained_action``). With ``U_c`` the union of the
    class-level signatures of class ``c``'s faults, the evidence is *unexplained* when

    .. math:: (D = 0 \\land E_c \\ne 0 \\land C = \\emptyset) \\lor
              (D \\ne 0 \\land E_c \\,\\&\\, \\lnot U_D \\ne 0)

    (a flag before its horizon that no fault of the isolated class explains, or flags no
    declared fault explains; the second term only with ``escalate``): the decision becomes the class ``unexplained`` (index
    ``len(classes) - 1``, latched) and its action is taken.
    """

    residuals: tuple[str, ...]
    window: int
    thresholds: np.ndarray
    confirm: int
    classes: tuple[str, ...]          # index 0 is "none"
    actions: tuple[str, ...]          # per class
    patterns: tuple[tuple[int, int], ...]  # (flag mask, class index)
    action_codes: tuple[int, ...] = field(default=())
    fault_names: tuple[str, ...] = ()
    fault_masks: tuple[int, ...] = ()        # signature mask per declared fault
    class_flags: int = -1    # residuals the class decision reads (all but fault-level ones)
    sq_max: float = 0.0               # Q_max of the equation above, for doubles
    sum_min: float = 0.0              # valid running sums: [sum_min, sum_max] (sum_limits)
    sum_max: float = 0.0
    horizons: tuple[int, ...] = ()    # H_i [samples] per residual (HORIZON_NONE: none)
    ambiguity: str = "most_severe"    # action policy while classes are ambiguous
    escalate: int = 1                 # 1: a flag the isolated class cannot explain escalates
    ambiguity_confirm: int = 0        # samples a non-unanimous action holds (0: confirm)
    startup: int = 0                  # samples from the start without a flag rising
    class_unions: tuple[int, ...] = field(default=())  # U_c, derived from the patterns

    def consistent_faults(self, flags: int) -> int:
        """The mask of declared faults whose signature holds every flag of ``flags`` (the
        evidence ``E = F & ~L``)."""
        if not flags:
            return 0
        return sum(1 << k for k, m in enumerate(self.fault_masks) if flags & ~m == 0)

    @property
    def unexplained(self) -> int:
        """Class index of ``unexplained`` (the last class)."""
        return len(self.classes) - 1

    @property
    def ambiguity_samples(self) -> int:
        """Samples the most severe of several actions must hold before it is taken."""
        return self.ambiguity_confirm or self.confirm

    @property
    def most_severe(self) -> int:
        """1 when the ambiguity policy takes the most severe action, 0 when it waits for
        every consistent class to call for the same action."""
        return int(self.ambiguity == "most_severe")

    def __post_init__(self):
        object.__setattr__(self, "action_codes",
                           tuple(ACTIONS.index(a) for a in self.actions))
        object.__setattr__(self, "sq_max", square_limit(self.window, np.float64))
        unions = [0] * len(self.classes)
        for m, c in self.patterns:
            unions[c] |= m
        unions[-1] = (1 << len(self.residuals)) - 1   # unexplained: nothing contradicts it
        object.__setattr__(self, "class_unions", tuple(unions))
        lo, hi = sum_limits(self.window, np.float64)
        object.__setattr__(self, "sum_min", lo)
        object.__setattr__(self, "sum_max", hi)

    def state_valid(self, counters_ok: bool, sums, oldest) -> list[bool]:
        """Per residual, whether its evaluation state is valid: the counters in range and
        ``S_min <= S_i <= S_max`` and ``0 <= oldest_i <= Q_max`` (NaN fails)."""
        return [bool(counters_ok and self.sum_min <= s <= self.sum_max
                     and 0.0 <= q <= self.sq_max) for s, q in zip(sums, oldest)]


#: Residuals a design holds at most: their flags are the bits of one 32-bit word, the
#: sign bit unused (every backend, the C core's ``int32_t``).
MAX_RESIDUALS = 31

#: the horizon of a residual without one (``INT32_MAX``: the frozen-sample count saturates
#: there, so it is never exceeded)
HORIZON_NONE = 2**31 - 1

#: A threshold that switches a residual's flag off (finite: the config needs it): the
#: healthy campaign's, and the stand-in ``fdigen inspect`` gives thresholds not designed yet.
NEVER_FLAGS = 1e30


def moving_rms(r: np.ndarray, window: int) -> np.ndarray:
    """The moving RMS of eq (22) of each column of ``r`` (samples x residuals), a
    non-finite sample counting as infinite:

    .. math:: \\mathrm{RMS}[k] = \\sqrt{\\tfrac{1}{N}\\sum_{l=k-N+1}^{k} r[l]^2}

    (the first ``N - 1`` samples over the samples so far, divided by ``N``, as the core
    starts from an empty window)."""
    r = np.asarray(r, dtype=float)
    sq = np.where(np.isfinite(r), r * r, np.inf)
    csum = np.cumsum(np.vstack([np.zeros((1, r.shape[1])), sq]), axis=0)
    lo = np.maximum(np.arange(1, r.shape[0] + 1) - window, 0)
    return np.sqrt((csum[1:] - csum[lo]) / window)


def class_level_masks(evaluation, outputs) -> dict:
    """Fault -> the flags of its signature the class decision reads, without the
    measurement-validity indicators ``nf_<y>`` of ``outputs`` (they rise only on an
    invalid sample)."""
    ev = evaluation
    validity = sum(1 << i for i, n in enumerate(ev.residuals)
                   if n in {f"nf_{o.name}" for o in outputs})
    return {n: m & ev.class_flags & ~validity for n, m in zip(ev.fault_names, ev.fault_masks)}


def horizon_samples(seconds: float | None, sample_time: float) -> int:
    """``H = floor(H_r / dt)`` samples (``HORIZON_NONE`` for no horizon)."""
    if seconds is None:
        return HORIZON_NONE
    return int(min(np.floor(seconds / sample_time + 1e-9), HORIZON_NONE))


def late_mask(horizons, frozen: int) -> int:
    """The residuals whose flag rising now is late: ``sum_i 2^i [frozen > H_i]``."""
    return sum(1 << i for i, h in enumerate(horizons) if frozen > h)


def square_limit(window: int, dtype) -> float:
    """``Q_max = max_finite / (2 N)`` of a floating type: squares up to it keep a running
    sum of ``N`` of them finite."""
    return float(dtype(np.finfo(dtype).max) / dtype(2 * window))


#: The class of evidence no declared fault explains (always the last class).
UNEXPLAINED = "unexplained"
#: The action policies of ``[fdi] ambiguity``.
AMBIGUITY_POLICIES = ("most_severe", "wait")
def sum_limits(window: int, dtype) -> tuple[float, float]:
    """The range ``[S_min, S_max]`` a running sum of ``N`` squares up to ``Q_max`` can take.

    .. math:: S_{min} = -N^2 \\varepsilon Q_{max},\\qquad S_{max} = N Q_{max} - S_{min}

    In exact arithmetic ``0 <= S <= N Q_max``; each of the ``N`` additions and subtractions
    a square stays in the window rounds by at most ``eps N Q_max``, hence the margin. A sum
    outside (NaN included) is a corrupted state.
    """
    q = dtype(square_limit(window, dtype))
    margin = dtype(window) * dtype(window) * dtype(np.finfo(dtype).eps) * q
    return float(-margin), float(dtype(window) * q + margin)


def threshold_array(cfg, names) -> np.ndarray:
    """The threshold of each residual of ``names`` from ``cfg.thresholds`` (0 for the
    sensor validity flags ``nf_*``, which compare a count, not an RMS)."""
    return np.array([cfg.thresholds.get(n, 0.0) if not n.startswith("nf_") else 0.0
                     for n in names], dtype=float)


def build_evaluation(model, cfg, names, table, fault_level=()):
    declared = tuple(sorted({f.fault_class for f in model.faults}))
    classes = ("none",) + declared + (UNEXPLAINED,)
    actions = ("none",) + tuple(cfg.actions[c] for c in declared) + (cfg.unexplained_action,)
    pairs = set()
    for f in model.faults:
        mask = sum(1 << names.index(r) for r in table[f.name])
        if mask:
            pairs.add((mask, classes.index(f.fault_class)))
    patterns = tuple(sorted(pairs))
    thresholds = threshold_array(cfg, names)
    masks = tuple(sum(1 << names.index(r) for r in table[f.name]) for f in model.faults)
    class_flags = sum(1 << i for i, n in enumerate(names) if n not in fault_level)
    patterns = tuple(sorted({(m & class_flags, c) for m, c in patterns if m & class_flags}))
    return Evaluation(names, cfg.window, thresholds, cfg.confirm, classes, actions, patterns,
                      fault_names=tuple(f.name for f in model.faults), fault_masks=masks,
                      class_flags=class_flags,
                      horizons=tuple(horizon_samples(cfg.frozen_horizon.get(n), cfg.sample_time)
                                     for n in names),
                      ambiguity=cfg.ambiguity,
                      escalate=int(cfg.escalate_after_isolation),
                      ambiguity_confirm=(0 if cfg.ambiguity_time is None else max(
                          cfg.confirm, int(np.ceil(cfg.ambiguity_time / cfg.sample_time
                                                   - 1e-9)))),
                      startup=startup_samples(cfg.startup, cfg.sample_time))


def startup_samples(startup: float, sample_time: float) -> int:
    """Samples of ``[fdi] startup`` seconds: :math:`\\lceil T_s / T \\rceil`."""
    return int(np.ceil(startup / sample_time - 1e-9)) if startup > 0 else 0
