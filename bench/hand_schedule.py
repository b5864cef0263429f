"""Constants of the scheduled R4/R5 predictions of the hand-written C step
(bench/handwritten/): :func:`schedule_constants`, used by :mod:`hand_consts`."""

from __future__ import annotations

import re

import numpy as np


def _exact(x):
    from fractions import Fraction
    return Fraction(float(x))


def schedule_constants(design, desc: dict, kal: dict, c: dict) -> dict | None:
    """Constants of the scheduled predictions of R4 and R5 (``schedule = "measured"``).

    The reduced Jacobians of both filters have one state-dependent entry each (checked
    against ``A_reduced_symbolic``, ``B_reduced_symbolic`` of design.json):

    * ``a = dPd'/dxdot = -A gamma (Pp/Vp + Pn/Vn)`` (R4: entry 0,2; R5: 0,1),
    * ``b = dPd'/dv = K R Ts gamma (1/Vp + 1/Vn) = K R Ts gamma (A L + 2 V0)/(Vp Vn)``,

    with ``Vp = A x + V0``, ``Vn = A (L - x) + V0``, evaluated at the clamped voted
    position and either the clamped measured pressures or the operating point's (per
    filter: which ``sched_*`` signals the design's program reads, e.g. R4 only the voted
    position, so that scheduling adds no pressure-sensor fault to its signature). The
    hand-written formulas are checked numerically against the design's program here.
    With ``E`` the unit matrix of the scheduled entry, the design's prediction matrices
    (:func:`fdigen.design.scheduled_prediction.scheduled_transition`)

        A_d(s) = A_d0 + h (A_r(s) - A_r0) + h^2/2 (A_r(s)^2 - A_r0^2)
               = A_d0 + (a - a0) (h E + h^2/2 (A_r0 E + E A_r0))        (E^2 = 0),
        B_d(s) = B_d0 + (b - b0) (h e_0 + h^2/2 A_r0 e_0)               (E B_r0 = 0),

    are affine in ``a`` and ``b``: entry = ``C + G a`` (or ``C + H b``), ``C`` folded once
    here (exact rational arithmetic on the design's doubles, rounded once). R5's reduced
    model is R4's without ``x`` (asserted), so both filters share ``C``, ``G``, ``H`` and
    ``b``, and every scheduled entry shares one division, ``1/(Vp Vn)``. ``None`` when
    neither filter is scheduled."""
    import sympy as sp

    specs = {k.residual: getattr(k, "schedule", "operating_point")
             for k in design.config.kalman}
    sched = {r: specs.get(r) == "measured" for r in ("R4", "R5", "R6")}
    assert not sched["R6"], "the hand-written step does not schedule R6"
    assert sched["R4"] == sched["R5"], \
        "the hand-written step schedules R4 and R5 together or neither"
    if not sched["R4"]:
        return None
    asg = {str(s): e for s, e in design.step.assignments}
    # the design divides once per distinct denominator (sched_inv<k> = 1/den): expand
    # those reciprocals so the entries below read in the scheduled signals only
    inv = {s: e for s, e in design.step.assignments if str(s).startswith("sched_inv")}
    asg = {n: e.xreplace(inv) if n.startswith(("R4_", "R5_")) else e for n, e in asg.items()}
    # R5's valve-gain entry and its B_d equal R4's: the design computes them once (R4's)
    expect = {"R4_Ar02", "R4_Br00", "R5_Ar01",
              "R4_Ad00", "R4_Ad02", "R4_Ad22", "R4_Bd00", "R4_Bd20",
              "R5_Ad00", "R5_Ad01", "R5_Ad11"}
    got = {n for n in asg if re.match(r"R[456]_(Ar|Br|Ad|Bd)\d\d$", n)}
    assert got == expect, f"scheduled entries of the design {sorted(got)}: the " \
        f"hand-written step computes {sorted(expect)}"
    st = {s.name: s for s in design.model.states}
    assert [tuple(map(str, st[n].limits)) for n in ("Pp", "Pn", "x")] == \
        [("Patm", "Psup"), ("Patm", "Psup"), ("0.0", "L")], "state limits changed"
    sig = {"sched_Pp": ("pp", "Patm", "Psup"), "sched_Pn": ("pn", "Patm", "Psup"),
           "sched_x": ("voter_out", "0.0", "L")}
    for name, (v, lo, hi) in sig.items():    # min(hi, max(lo, v)), as the hand-written
        if name in asg:
            assert str(asg[name]) == f"Min({hi}, Max({lo}, {v}))", (name, asg[name])
    op = desc["operating_point"]   # A_d (z+ - z0) + B_d (u - u0): only x0 != 0, column e1
    assert op["Pp"] == op["Pn"] and op["xdot"] == 0 and op["v"] == 0, op
    # the physics the hand-written step uses, against the design's symbolic Jacobian
    Patm, Psup, L = (sp.Symbol(n) for n in ("Patm", "Psup", "L"))
    A, g, K, R, Ts, V0, Pp, Pn, x = sp.symbols("A gamma K R Ts V0 Pp Pn x")
    Vp, Vn = A * x + V0, A * (L - x) + V0
    a_s = -A * g * (Pp / Vp + Pn / Vn)
    b_s = K * R * Ts * g * (A * L + 2 * V0) / (Vp * Vn)
    loc = {str(v): v for v in (A, g, K, R, Ts, V0, Pp, Pn, x, L)}
    for res, (i, j), n in (("R4", (0, 2), 3), ("R5", (0, 1), 2)):
        As = [[sp.sympify(e, locals=loc) for e in row] for row in kal[res]["A_reduced_symbolic"]]
        Bs = [[sp.sympify(e, locals=loc) for e in row] for row in kal[res]["B_reduced_symbolic"]]
        states = {Pp, Pn, x, sp.Symbol("xdot")}
        dep = [(r, q) for r in range(n) for q in range(n) if As[r][q].free_symbols & states]
        assert dep == [(i, j)], f"{res}: state-dependent A_r entries {dep}"
        assert sp.simplify(As[i][j] - a_s) == 0, f"{res}: A_r[{i},{j}] = {As[i][j]}"
        depb = [r for r in range(n) if Bs[r][0].free_symbols & states]
        assert depb == [0] and sp.simplify(Bs[0][0] - b_s) == 0, f"{res}: B_r = {Bs}"
    # which measured signals each filter's schedule reads, and the formulas in floats
    par = {q.name: float(q.value) for q in design.model.parameters}
    pv = {A: par["A"], g: par["gamma"], K: par["K"], R: par["R"], Ts: par["Ts"],
          V0: par["V0"], L: par["L"]}
    measured = {}
    for res, an in (("R4", "R4_Ar02"), ("R5", "R5_Ar01")):
        fa = {str(q) for q in asg[an].free_symbols}
        fb = {str(q) for q in asg["R4_Br00"].free_symbols}
        assert fa in ({"sched_x"}, {"sched_x", "sched_Pp", "sched_Pn"}) and \
            fb == {"sched_x"}, f"{res} scheduled on {sorted(fa)}, {sorted(fb)}: the " \
            "hand-written step knows the voted position, with or without the pressures"
        measured[res] = "sched_Pp" in fa
        for xs, pps, pns in ((0.0, 2.0e5, 4.5e5), (0.031, 6.0e5, 1.01325e5),
                             (0.1, 3.5e5, 3.5e5), (0.2, 1.2e5, 5.5e5)):
            at = {sp.Symbol("sched_x", real=True): xs, sp.Symbol("sched_Pp", real=True): pps,
                  sp.Symbol("sched_Pn", real=True): pns}
            at = {q: at[sp.Symbol(str(q), real=True)] for q in asg[an].free_symbols}
            pe = (pps, pns) if measured[res] else (op["Pp"], op["Pn"])
            want_a = float(a_s.subs(pv).subs({x: xs, Pp: pe[0], Pn: pe[1]}))
            want_b = float(b_s.subs(pv).subs({x: xs}))
            got_a = float(asg[an].xreplace(at))
            got_b = float(asg["R4_Br00"].xreplace(
                {q: xs for q in asg["R4_Br00"].free_symbols}))
            assert abs(got_a - want_a) <= 1e-12 * abs(want_a), (res, xs, got_a, want_a)
            assert abs(got_b - want_b) <= 1e-12 * abs(want_b), (res, xs, got_b, want_b)
    h = _exact(desc["sample_time"])
    A0 = [[_exact(v) for v in row] for row in kal["R4"]["A_reduced"]]
    B0 = [_exact(row[0]) for row in kal["R4"]["B_reduced"]]
    Ad0 = [[_exact(v) for v in row] for row in kal["R4"]["A_discrete"]]
    Bd0 = [_exact(row[0]) for row in kal["R4"]["B_discrete"]]
    # R5 = R4 without x (coordinates Pd, xdot): the same numbers, rows/columns 0 and 2
    for key in ("A_reduced", "A_discrete", "B_reduced", "B_discrete"):
        r4 = np.array(kal["R4"][key], dtype=float)
        r5 = np.array(kal["R5"][key], dtype=float)
        sub = r4[np.ix_([0, 2], [0, 2])] if key.startswith("A") else r4[[0, 2]]
        assert np.allclose(sub, r5, rtol=1e-12, atol=0), (key, sub, r5)
    a0, b0 = A0[0][2], B0[0]
    # E = e0 e2^T: A_r0 E has column 2 = A_r0[:, 0]; E A_r0 has row 0 = A_r0[2, :]
    G = [[(h if (r, q) == (0, 2) else 0) + h * h / 2 * ((A0[r][0] if q == 2 else 0)
                                                        + (A0[2][q] if r == 0 else 0))
          for q in range(3)] for r in range(3)]
    Hb = [h * (1 if r == 0 else 0) + h * h / 2 * A0[r][0] for r in range(3)]
    assert B0[2] == 0, "E B_r0 != 0: the hand-written B_d(s) omits that term"
    nzA = {(r, q) for r in range(3) for q in range(3) if G[r][q] != 0}
    assert nzA == {(0, 0), (0, 2), (2, 2)} and G[0][0] == G[2][2], G
    assert {r for r in range(3) if Hb[r] != 0} == {0, 2}, Hb
    lit = float     # rounded once
    return {
        "a0": float(a0), "b0": float(b0), "op_P": float(op["Pp"]),
        "R4_measured_pressures": measured["R4"], "R5_measured_pressures": measured["R5"],
        "A00": lit(Ad0[0][0] - G[0][0] * a0), "A02": lit(Ad0[0][2] - G[0][2] * a0),
        "A22": lit(Ad0[2][2] - G[2][2] * a0), "GA0": lit(G[0][0]), "GA02": lit(G[0][2]),
        "B0": lit(Bd0[0] - Hb[0] * b0), "B2": lit(Bd0[2] - Hb[2] * b0),
        "HB0": lit(Hb[0]), "HB2": lit(Hb[2]),
    }
