"""The RK4 sub-steps of the plant simulator, chosen or checked for numerical stability.

The simulator integrates the plant over each sample time by ``substeps`` classical
Runge-Kutta steps. A stiff model (a fast electrical or pressure mode) at a long sample
time makes too few steps amplify a mode the plant damps, and the simulation diverges to
the states' limits without any other sign. The check is the FDI design's
(:mod:`fdigen.derive.rk4_stability`): the linearised modes at the operating point and at
the ends of every state's ``range``.
"""

from __future__ import annotations

from fdigen.derive.rk4_stability import least_stable_substeps, linearised_modes, unstable_mode
from fdigen.errors import ModelFileError
from fdigen.model.model import Model

#: sub-steps of a model that gives no ``[simulation] substeps`` when that count is stable
DEFAULT_SUBSTEPS = 10

_MODES_CACHE: dict = {}


def model_modes(model: Model):
    """The model's linearised modes (:func:`fdigen.derive.rk4_stability.linearised_modes`),
    kept per model (its ``[simulation]`` table left out: the modes do not read it, and
    each run of a campaign varies its demand)."""
    import dataclasses

    from fdigen.model.model_file import model_hash

    key = model_hash(dataclasses.replace(model, simulation={}))
    if key not in _MODES_CACHE:
        if len(_MODES_CACHE) > 32:
            _MODES_CACHE.clear()
        _MODES_CACHE[key] = linearised_modes(model)
    return _MODES_CACHE[key]


def simulation_substeps(model: Model, dt: float, substeps: int | None = None) -> int:
    """RK4 sub-steps per sample of the simulated plant.

    ``substeps`` (the caller's) or ``[simulation] substeps`` when given, refused when
    unstable; otherwise the larger of :data:`DEFAULT_SUBSTEPS` and the least count for
    which every linearised mode ``lambda`` satisfies
    ``|R(lambda h)| <= max(1, |e^{lambda h}|)``, ``h = dt / substeps``.

    Raises
    ------
    ModelFileError
        An explicit count that RK4 integrates unstably, naming the mode and the least
        stable count.
    """
    given = substeps or model.simulation.get("substeps")
    modes = model_modes(model)
    if not given:
        return least_stable_substeps(modes, dt, DEFAULT_SUBSTEPS)
    mode = unstable_mode(modes, dt, int(given))
    if mode is not None:
        raise ModelFileError(
            f"the simulated plant's RK4 integration is unstable at step {mode.step:g} s: "
            f"the linearised mode {mode.lam:.4g} 1/s at {mode.where()} gives "
            f"|R(lambda h)| = {mode.amplification:.3g} > 1; use substeps >= {mode.need} "
            f"(or leave simulation.substeps out to have it chosen)",
            model.source, "simulation.substeps", str(int(given)))
    return int(given)


#: the most a campaign raises the plant's sub-steps over the model's own count
CAMPAIGN_SUBSTEP_FACTOR = 4


def campaign_substeps(model: Model, dt: float, parameter_sets) -> dict | None:
    """RK4 sub-steps that integrate the plant stably at every one of ``parameter_sets``
    (a campaign's tolerance vertices), when that is more than
    :func:`simulation_substeps` at the model's own values; else ``None``.

    The count is checked at the model's parameter values; a campaign that spreads them
    simulates other plants. A user's chemostat with its oxygen transfer 10 % higher left
    RK4's stability region at the 12 sub-steps chosen at nominal: the simulated oxygen
    fell from 78 % to 0.1 % in one sample, a better-aerated plant read as a dead probe,
    and the thresholds came out at 4 times the sensor's span.

    Returns
    -------
    dict or None
        ``nominal`` (the model's count), ``needed`` (the least stable at every set),
        ``used`` (``needed``, at most :data:`CAMPAIGN_SUBSTEP_FACTOR` times ``nominal``:
        a vertex that needed 31,904 made a 4-run campaign take hours), ``at`` (the set
        that needed the most).
    """
    nominal = simulation_substeps(model, dt)
    need, at = nominal, None
    for pars in parameter_sets:
        if not pars:
            continue
        n = least_stable_substeps(linearised_modes(model, pars), dt, need)
        if n > need:
            need, at = n, dict(pars)
    if need <= nominal:
        return None
    return {"nominal": nominal, "needed": need, "at": at,
            "used": min(need, CAMPAIGN_SUBSTEP_FACTOR * nominal)}
