"""Explain: choose the library effect(s) that account for the located structure.

Forward selection with an information criterion, checked on held-back data:

1. Candidates: in the first round every applicable library effect; in later rounds the
   effects whose footprint (the equations they change,
   :meth:`LibraryEffect.footprint`) meets an equation still located.
2. Each candidate is fitted together with the uncertain parameters on the calibration
   windows (:func:`fdigen.discover.calibrate.calibrate`, same equation weights as the
   nominal fit, so the weighted sums of squares ``S`` compare). With the weights at the
   noise level, ``S`` is a chi-square and BIC reads

   .. math::

       \\mathrm{BIC} = S_{cal} + k \\ln N_{cal}, \\qquad
       \\Delta\\mathrm{BIC} = S_{cal}^{new} - S_{cal}^{old} + k \\ln N_{cal},

   ``k`` the candidate's parameter count, ``N`` the number of weighted residuals.
3. The candidate with the lowest BIC is accepted only if ``Delta BIC < -bic_margin``
   **and** it lowers the held-back (validation) sum of squares by more than the
   chi-square quantile ``chi2_{k}(1 - alpha_validation)`` (default 5 %: 3.84 for one
   parameter) with the parameters fitted on the calibration part alone (out-of-sample
   confirmation; the discovery itself is the BIC test, ``Delta S > 10 + ln N``, about
   a 4-sigma effect) -- or, when the held-back part holds too little information on the
   parameter for that (its excitation was in the calibration part), a positive held-back
   gain and a held-back estimate that agrees with the calibration one within
   ``consistency`` (3) standard deviations. From the second round on, the candidate must
   also remove at least ``min_gain`` of the excess sum of squares of the equations still
   located (``S - N``): a further effect must explain the structure that remains, not
   polish the fit.
4. The located equations are re-tested with the effect in; if structure remains, the
   next effect is sought the same way (at most ``max_effects``).
5. Ties: candidates within ``TIE`` (2) of the best BIC change, each significant, are
   the same to the equation error (a constant offset of a metered inflow, a linear leak
   and the outlet valve's constant are nearly collinear over a tank's levels). When
   ``free_run`` is given, one free run of the validation part with each candidate's fit
   decides among them: the candidate whose worst output error (in sensor noise levels)
   is below ``FREE_RUN_DECIDES`` (0.5) times that of the best-BIC one is chosen in its
   place, and said.
6. Library-directed search: the first round scores every applicable effect even when
   the generic test locates nothing; its best candidate is then confirmed only by its
   held-back gain, at ``alpha_validation / n`` for ``n`` candidates scored (Bonferroni:
   the best of ``n`` passes the uncorrected test by chance ``n`` times as often). This
   finds effects that a calibrated parameter nearly absorbs (a leak
   across the piston is almost collinear with the valve constant in closed loop, so the
   residual left after calibration is small and not visibly structured, yet the one
   extra parameter lowers the sum of squares by far more than noise can). On healthy
   simulated and rig logs the best candidate's BIC change stays above +2, far from the
   -10 needed.

A healthy log with a correct model locates nothing, so nothing is chosen; when structure
is located but no library effect passes the three checks, the result says so (the
discrepancy is outside the library).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from fdigen.discover.calibrate import Fit, calibrate, noise_levels
from fdigen.discover.effects import LibraryEffect, library
from fdigen.discover.locate import EquationData, EquationTest, locate

#: BIC difference below which two significant candidates are tied.
TIE = 2.0
#: A tied candidate replaces the best-BIC one when its free-run error is below this share
#: of the latter's.
FREE_RUN_DECIDES = 0.5


@dataclass
class Candidate:
    """One candidate effect's fit and its scores.

    Attributes
    ----------
    effect : str
    parameters : dict
        Its parameter estimates.
    std : dict
        Their standard deviations.
    delta_bic : float
        BIC change on the calibration part (negative: better).
    gain_validation : float
        Decrease of the weighted validation sum of squares.
    gain_share : float
        Share of the located equations' excess sum of squares removed (calibration).
    accepted : bool
    round : int
    free_run : float or None
        Worst output error of one free run of the validation part, in sensor noise
        levels, where a tie was decided by it (step 5).
    """

    effect: str
    parameters: dict
    std: dict
    delta_bic: float
    gain_validation: float
    gain_share: float
    accepted: bool = False
    round: int = 1
    validation_estimate: dict = field(default_factory=dict)
    validation_z: float | None = None
    free_run: float | None = None

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass
class Explanation:
    """The outcome of :func:`explain`.

    Attributes
    ----------
    effects : list of LibraryEffect
        The chosen effects (empty: nothing significant).
    fit : Fit
        The final fit (the nominal one if no effect was chosen).
    tests : list of EquationTest
        The final model's equation tests (calibration part).
    candidates : list of Candidate
        Every candidate tried, in every round.
    message : str
    """

    effects: list
    fit: Fit
    tests: list
    candidates: list = field(default_factory=list)
    message: str = ""


def candidates_for(data: EquationData, equations, exclude=()) -> list[LibraryEffect]:
    """Applicable library effects whose footprint meets ``equations``."""
    model = data.model
    testable = set(data.equations)
    out = []
    for e in library(model):
        if e.name in exclude:
            continue
        fp = e.footprint(model) & testable
        if fp & set(equations):
            out.append(e)
    return out


def explain(data: EquationData, base: Fit, tests: list[EquationTest], cal: np.ndarray,
            val: np.ndarray, *, alpha: float = 1e-3, alpha_validation: float = 0.05,
            consistency: float = 3.0, bic_margin: float = 10.0,
            min_gain: float = 0.2, max_effects: int = 2, locate_options: dict | None = None,
            library_search: bool = True, free_run=None, log=None) -> Explanation:
    """Choose the effect(s) explaining the located structure (see the module docstring).

    Parameters
    ----------
    data : EquationData
    base : Fit
        Calibrated nominal model.
    tests : list of EquationTest
        Its equation tests (from :func:`fdigen.discover.locate.locate`).
    cal, val : numpy.ndarray
        Calibration and validation windows.
    alpha, alpha_validation, bic_margin, min_gain, max_effects
        Acceptance thresholds (see the module docstring); ``alpha`` is kept for the
        re-tests, ``alpha_validation`` is the level of the held-back confirmation.
    consistency : float
        Largest standardised difference between the calibration and the held-back
        estimates when the held-back gain alone does not confirm (see step 3).
    locate_options : dict, optional
        Options of the re-test after each accepted effect.
    library_search : bool
        Score every applicable effect in the first round (not only those acting in a
        located equation).
    free_run : callable, optional
        ``free_run(effects, params) -> float or None``: the worst output error of one
        free run of the validation part in sensor noise levels; decides ties (step 5).
    log : callable, optional
        Progress messages.
    """
    locate_options = dict(locate_options or {})
    say = log or (lambda msg: None)
    chosen: list[LibraryEffect] = []
    current, cur_tests = base, tests
    tried: list[Candidate] = []
    n_cal = int(cal.sum()) * len(data.equations)
    rounds = 0
    directed = False
    while rounds < max_effects:
        located = [t.equation for t in cur_tests if t.located]
        search = located
        if rounds == 0 and library_search:
            # first round: every applicable effect is scored, also those acting outside
            # the located equations (an effect nearly collinear with a calibrated
            # parameter leaves a small, barely structured residual)
            directed = not located
            search = list(data.equations)
        elif not located:
            break
        rounds += 1
        cands = candidates_for(data, search, exclude={e.name for e in chosen})
        if not cands:
            break
        loc_idx = [data.equations.index(q) for q in (located or search)]
        excess = float(np.sum((current.E[cal][:, loc_idx] / current.sigma[loc_idx]) ** 2)) \
            - int(cal.sum()) * len(loc_idx)
        scored = []
        for e in cands:
            fit = calibrate(data, cal, [*chosen, e], sigma=base.sigma,
                            start={k: v for k, v in current.params.items()
                                   if k in current.free})
            k = len(e.parameters)
            d_bic = fit.sse_on(cal) - current.sse_on(cal) + k * np.log(n_cal)
            gain_val = current.sse_on(val) - fit.sse_on(val)
            gain_loc = float(np.sum((current.E[cal][:, loc_idx] / base.sigma[loc_idx]) ** 2)
                             - np.sum((fit.E[cal][:, loc_idx] / base.sigma[loc_idx]) ** 2))
            share = gain_loc / excess if excess > 0 else 0.0
            cand = Candidate(e.name, {p: fit.params[p] for p in e.parameter_names},
                             {p: fit.std.get(p, float("nan")) for p in e.parameter_names},
                             float(d_bic), float(gain_val), float(share), round=rounds)
            scored.append((d_bic, cand, fit, e))
            tried.append(cand)
            say(f"  candidate {e.name}: dBIC {d_bic:.1f}, validation gain {gain_val:.1f}, "
                f"share {share:.2f}")
        scored.sort(key=lambda s: s[0])
        if free_run is not None:
            _decide_tie(scored, chosen, bic_margin, free_run, say)
        d_bic, cand, fit, e = scored[0]
        # a search that located nothing picks the best of every applicable effect: its
        # confirmation is corrected for that many tries (Bonferroni), and must be the
        # held-back gain itself (a first-time user's healthy mass-spring log: the best of
        # four, a Stribeck friction, passed with dBIC -11.1 and a gain of 5.5 > 3.84)
        alpha = alpha_validation / len(scored) if directed and rounds == 1 else \
            alpha_validation
        crit = float(stats.chi2.ppf(1 - alpha, len(e.parameters)))
        confirmed = cand.gain_validation > crit
        if not confirmed and cand.gain_validation > 0 and d_bic < -bic_margin \
                and not (directed and rounds == 1):
            # the held-back part may hold little information on this parameter (the
            # excitation was in the calibration part): then ask that it does not
            # contradict the estimate, i.e. a fit on the held-back part alone agrees
            vfit = calibrate(data, val, [*chosen, e], sigma=base.sigma,
                             start={k: v for k, v in fit.params.items() if k in fit.free})
            zs = []
            for p in e.parameter_names:
                sd = np.hypot(fit.std.get(p, np.nan), vfit.std.get(p, np.nan))
                zs.append(abs(fit.params[p] - vfit.params[p]) / sd if sd > 0 else np.inf)
            cand.validation_estimate = {p: vfit.params[p] for p in e.parameter_names}
            cand.validation_z = float(max(zs))
            confirmed = cand.validation_z <= consistency
        explains = rounds == 1 and library_search or cand.gain_share > min_gain
        if d_bic < -bic_margin and confirmed and explains:
            cand.accepted = True
            chosen.append(e)
            current = fit
            cur_tests = locate(data, fit.E, cal, **locate_options)
        else:
            break
    if chosen:
        # final fit re-weighted with the noise levels of the explained residual, so that
        # the parameter covariance s^2 (J^T J)^-1 uses the right noise per equation
        sigma = noise_levels(current.E, cal)
        current = calibrate(data, cal, chosen, sigma=sigma,
                            start={k: v for k, v in current.params.items()
                                   if k in current.free})
        cur_tests = locate(data, current.E, cal, **locate_options)
        names = ", ".join(e.name for e in chosen)
        left = [t.equation for t in cur_tests if t.located]
        msg = f"effect found: {names}" + (
            " (by the library-directed search: no equation error looked structured on its "
            "own)" if directed else "") + (
            f"; structure remains in {', '.join(left)}" if left else "")
    elif any(t.located for t in tests) and not directed:
        msg = ("structure located in " + ", ".join(t.equation for t in tests if t.located)
               + " but no library effect explains it significantly")
    else:
        msg = "no unexplained structure in the equation errors (no effect)"
    return Explanation(chosen, current, cur_tests, tried, msg)


def _decide_tie(scored: list, chosen: list, bic_margin: float, free_run, say) -> None:
    """Put first, in ``scored`` (sorted by BIC change), the tied candidate whose free run
    of the validation part is decisively better (step 5 of the module docstring)."""
    best = scored[0][0]
    tied = [s for s in scored if s[0] < -bic_margin and s[0] - best < TIE]
    if len(tied) < 2:
        return
    for s in tied:
        s[1].free_run = free_run([*chosen, s[3]], s[2].params)
    known = [s for s in tied if s[1].free_run is not None and np.isfinite(s[1].free_run)]
    first = scored[0][1].free_run
    if not known or first is None:
        return
    winner = min(known, key=lambda s: s[1].free_run)
    if winner is scored[0] or winner[1].free_run >= FREE_RUN_DECIDES * first:
        return
    say(f"  {winner[3].name} and {scored[0][3].name} tie on the equation error (dBIC "
        f"{winner[0]:.1f} and {best:.1f}); one free run of the validation part decides: "
        f"{winner[1].free_run:.3g}x against {first:.3g}x the sensor noise")
    scored.remove(winner)
    scored.insert(0, winner)

