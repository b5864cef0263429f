"""What the commissioning log shows of the plant: a measured state that never reverses.

A user's drive train was commissioned on a 10 s log whose speeds never changed sign,
although their declared ranges span both directions (``wm``, ``wl`` in -100..100 rad/s).
Its backlash and dry friction act at a reversal: the log could not show them, the
calibration put their constant part into a current-sensor offset, and the design raised
a flag on every other healthy log of the rig at its first reversal. Nothing said the log
had never been where the faults of the design would be judged.

A hydraulic axis logged on a slow ramp out (its position's range does not hold zero) has
the same blind spot in its velocity: a rate state ``v`` of a measured ``x``
(``dx/dt = c v``) is read as the smoothed derivative of ``x``.

For each measured state (:func:`fdigen.discover.locate.measured_states`), and rate state,
whose declared
``range`` :math:`[r_{lo}, r_{hi}]` holds zero, with :math:`x_{lo}, x_{hi}` the 0.5 % and
99.5 % quantiles of the state read from its sensors over the log, the log *reverses* it
when it goes a twentieth of the range's way on either side,

.. math:: x_{lo} < r_{lo}/20 \\quad\\text{and}\\quad x_{hi} > r_{hi}/20

(an encoder's one count around standstill, -3.07 rad/s on a 100 rad/s range, is no
reversal); a state it never reverses is warned of.
"""

from __future__ import annotations

import numpy as np

#: The share of each side of a range a log must reach on both sides to reverse a state.
REVERSAL_SHARE = 0.05


def _read_states(model, y, dt: float | None) -> dict:
    """State index -> its values over the log: a measured state's from its sensors, and
    a rate state ``v`` of a measured ``x`` (``dx/dt = c v``, a cylinder's velocity under
    its position) as the measured one's derivative over ``c``, smoothed over 1 % of the
    log (at least 5 samples); the latter only with the sample time ``dt``."""
    from fdigen.discover.locate import chain_gain, measured_states, state_values

    measured = measured_states(model)
    out = {}
    for i, outs in measured.items():
        try:
            out[i] = np.asarray(state_values(model, outs, y), dtype=float)
        except Exception:  # noqa: BLE001 - a map that cannot be read says nothing here
            continue
    if not dt:
        return out
    f = model.f()
    for j, st in enumerate(model.states):
        if j in out:
            continue
        for i in measured:
            c = chain_gain(model, f[i], st.symbol) if i in out else None
            if c is None:
                continue
            x = out[i]
            n = max(5, len(x) // 100)
            smooth = np.convolve(np.nan_to_num(x, nan=float(np.nanmean(x))),
                                 np.ones(n) / n, mode="valid")
            out[j] = np.diff(smooth) / (dt * c)
            break
    return out


def unreversed_states(model, y, dt: float | None = None) -> list[dict]:
    """States whose declared range holds zero and which the log ``y`` (K, p) never
    reverses (measured ones, and with the sample time ``dt`` the rates of measured ones):
    ``state``, ``range``, ``seen`` (the quantiles) and ``read`` (how) each."""
    from fdigen.discover.locate import measured_states

    measured = measured_states(model)
    out = []
    for i, x in _read_states(model, y, dt).items():
        st = model.states[i]
        if not st.range:
            continue
        lo, hi = float(st.range[0]), float(st.range[1])
        if not lo < 0.0 < hi:
            continue
        x = x[np.isfinite(x)]
        if x.size < 10:
            continue
        seen = np.quantile(x, [0.005, 0.995])
        if not (seen[0] < REVERSAL_SHARE * lo and seen[1] > REVERSAL_SHARE * hi):
            out.append({"state": st.name, "range": [lo, hi],
                        "seen": [float(seen[0]), float(seen[1])],
                        "read": "measured" if i in measured else "rate"})
    return out


def coverage_warning(model, y, dt: float | None = None) -> str:
    """The warning of :func:`unreversed_states` ("" when the log reverses them all)."""
    states = unreversed_states(model, y, dt)
    if not states:
        return ""
    units = {s.name: f" {s.unit}" if getattr(s, "unit", "") else "" for s in model.states}
    return ("the log never reverses " + ", ".join(
        f"{e['state']} ({e['seen'][0]:.4g} to {e['seen'][1]:.4g}{units[e['state']]} of its "
        f"range {e['range'][0]:g} to {e['range'][1]:g}"
        + (", read as the rate of a measured state" if e["read"] == "rate" else "") + ")"
        for e in states)
        + ": effects that act at a reversal (dry friction, backlash, a one-way valve) "
        "cannot show in it, and what it shows of them (their constant part) may be read as "
        "another effect; a log that covers both directions shows them, and `fdigen "
        "commission --validate` checks a design on one")
