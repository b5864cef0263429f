"""The parameter spread of commissioning's campaigns: each calibrated parameter's own.

A calibration on one log gives each uncertain parameter an interval; the campaigns that
design and check the thresholds spread each parameter by its own interval times
``sigmas``, at least a floor (the rig drifts between runs) and at most
:data:`MAX_TOLERANCE`.
"""

from __future__ import annotations

import math

#: The widest relative spread a campaign (and a parameter's ``tolerance``) takes: an offset
#: calibrated near 0 (-0.087 +- 0.10) gave +-355 %, a ``tolerance`` the model file refuses
#: (attack round 3: the commissioned file could not be read back).
MAX_TOLERANCE = 0.9


def campaign_tolerance(params: dict, std: dict, sigmas: float, floor: float) -> float:
    """Largest relative spread of the campaign: ``max(sigmas * max_k std_k/|theta_k|,
    floor)`` (the spread of the uncertain parameters the calibration gave no interval)."""
    return float(max([*campaign_tolerances(params, std, sigmas, floor).values(), floor]))


def campaign_tolerances(params: dict, std: dict, sigmas: float, floor: float) -> dict:
    """Each calibrated parameter's own spread,
    ``min(max(sigmas * std_k/|theta_k|, floor), MAX_TOLERANCE)``.

    One spread for all (the largest) put a heat loss known to +-34 % on an outflow
    coefficient known to 0.15 %: the level residual's threshold went to 1.6 times its
    sensor's span and the design was refused.
    """
    return {k: float(min(max(sigmas * abs(std[k] / params[k]), floor), MAX_TOLERANCE))
            for k in std      # None: held at its datasheet value (no interval)
            if k in params and params[k] and std[k] is not None and math.isfinite(std[k])}


def wide_intervals(params: dict, std: dict, sigmas: float) -> list[str]:
    """A warning per calibrated parameter whose spread is capped at :data:`MAX_TOLERANCE`."""
    out = []
    for k, v in params.items():
        s = std.get(k)
        if v and s is not None and math.isfinite(s) and sigmas * abs(s / v) > MAX_TOLERANCE:
            out.append(f"{k} calibrated to {v:.4g} +- {s:.2g}: {sigmas:g} sigma is "
                       f"+-{100 * sigmas * abs(s / v):.3g} % of the value, so the campaigns "
                       f"spread it +-{100 * MAX_TOLERANCE:g} %: the log hardly determines it")
    return out


def round_up(value: float, digits: int = 3) -> float:
    """``value`` rounded up to ``digits`` significant digits (a spread never understated)."""
    if value <= 0:
        return 0.0
    scale = 10.0 ** (math.floor(math.log10(value)) - digits + 1)
    return float(f"{math.ceil(value / scale - 1e-9) * scale:.{digits}g}")
