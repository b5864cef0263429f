"""The FDI step written the way a Python user would with the usual libraries: the three
Kalman residuals as ``filterpy.kalman.KalmanFilter`` objects with the design's
steady-state gains (``update_steadystate`` / ``predict_steadystate``), numpy for the rest
(three parallel models RK4 with dedicated parity realignment, R7, R8, R9, voter, moving
RMS, flags, frozen horizon, isolation, the action policy under ambiguity and the
contradiction of the isolated class). A benchmark peer only (bench/run.py): filterpy is a
bench dependency, never fdigen's.

The constants are those of the hand-written C (:func:`hand_consts.design_constants`).
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter


def _kf(A, B, C, M):
    kf = KalmanFilter(dim_x=A.shape[0], dim_z=1, dim_u=B.shape[1])
    kf.F, kf.B, kf.H = A.copy(), B.copy(), C.copy()
    kf.K = M.reshape(-1, 1).copy()
    return kf


class FilterpyFdi:
    """Per-sample FDI step: ``step(u, y) -> dict`` (r, rms, flags, fault_class, action,
    aux), ``run(u, y)`` loops over a log."""

    def __init__(self, c: dict):
        self.c = c
        (self.gamma, self.R, self.Ts, self.A, self.M, self.Ff, self.L, self.V0, self.K,
         self.Psup, self.Patm, self.P0) = c["parameters"]
        self.nr = len(c["names"])
        self.thr = np.array(c["thresholds"])
        self.reset()

    def reset(self):
        c = self.c
        self.kf4 = _kf(c["R4"]["A"], c["R4"]["B"], c["R4"]["C"], c["R4"]["M"])
        self.kf5 = _kf(c["R5"]["A"], c["R5"]["B"], c["R5"]["C"], c["R5"]["M"])
        self.kf6 = _kf(c["R6"]["A"], c["R6"]["B"], c["R6"]["C"], c["R6"]["M"])
        self.par = None          # parallel models [Pp, Pn, x, xdot] of R1, R2, R3 (3 x 4)
        self.r7 = None           # [m, xdot]
        self.r8 = self.r9 = None  # [Pp, x, xdot], [Pn, x, xdot]
        self.frozen, self.late = 0, 0
        self.buf = np.zeros((c["window"], self.nr))
        self.sums = np.zeros(self.nr)
        self.index = 0
        self.flags = 0
        self.candidate = self.count = self.decision = 0
        self.action_candidate = self.action_count = self.action = 0

    def _f(self, s, v):
        Pp, Pn, x, xd = s
        A = self.A
        Vp = A * x + self.V0
        Vn = A * (self.L - x) + self.V0
        kgv = self.K * self.R * self.Ts * self.gamma * v
        return np.array([(kgv - self.gamma * A * Pp * xd) / Vp,
                         (self.gamma * A * Pn * xd - kgv) / Vn, xd,
                         (A * (Pp - Pn) - self.Ff * xd) / self.M])

    def _rk4_reduced(self, s, v, measured, chamber):
        """One RK4 step of R8 (chamber 0: Pp simulated, pn measured) or R9 (chamber 1)."""
        A, dt = self.A, self.c["dt"]
        kgv = self.K * self.R * self.Ts * self.gamma * v

        def f(q):
            P, x, xd = q
            if chamber == 0:
                dP = (kgv - self.gamma * A * P * xd) / (A * x + self.V0)
                dpn = P - measured
            else:
                dP = (self.gamma * A * P * xd - kgv) / (A * self.L + self.V0 - A * x)
                dpn = measured - P
            return np.array([dP, xd, A / self.M * dpn - self.Ff / self.M * xd])
        k1 = f(s)
        k2 = f(s + 0.5 * dt * k1)
        k3 = f(s + 0.5 * dt * k2)
        k4 = f(s + dt * k3)
        nxt = s + dt / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)
        nxt[0] = min(self.Psup, max(self.Patm, nxt[0]))
        nxt[1] = min(self.L, max(0.0, nxt[1]))
        return nxt

    def _schedule(self, pp, pn, xv):
        """Scheduled prediction matrices of R4 and R5 (``schedule = "measured"``): the
        Jacobian entries at the voted position and, per filter, the measured pressures or
        the operating point's, clamped to their limits, and the design's affine discrete
        entries (constants of :func:`hand_schedule.schedule_constants`); R5's model is R4's
        without x."""
        s = self.c["sched"]
        x = min(self.L, max(0.0, xv))
        Vp = self.A * x + self.V0
        Vn = self.A * (self.L - x) + self.V0
        b = self.K * self.R * self.Ts * self.gamma * (1.0 / Vp + 1.0 / Vn)
        B4, B5 = self.kf4.B, self.kf5.B
        B4[0, 0] = B5[0, 0] = s["B0"] + s["HB0"] * b
        B4[2, 0] = B5[1, 0] = s["B2"] + s["HB2"] * b
        for kf, measured, k in ((self.kf4, s["R4_measured_pressures"], 2),
                                (self.kf5, s["R5_measured_pressures"], 1)):
            if measured:
                Pp = min(self.Psup, max(self.Patm, pp))
                Pn = min(self.Psup, max(self.Patm, pn))
            else:
                Pp = Pn = s["op_P"]
            a = -self.gamma * self.A * (Pp / Vp + Pn / Vn)
            kf.F[0, 0] = s["A00"] + s["GA0"] * a
            kf.F[0, k] = s["A02"] + s["GA02"] * a
            kf.F[k, k] = s["A22"] + s["GA0"] * a

    def step(self, u, y):
        c = self.c
        v = float(u[0])
        x3, x2, pp, pn = (float(q) for q in y)
        nf = []
        if c["guards"]:
            b = c["bounds"]
            ok = [abs(x3) <= b["x"], abs(x2) <= b["x"], abs(pp) <= b["p"], abs(pn) <= b["p"]]
            v = v if abs(v) <= b["v"] else b["v_fallback"]
            if self.par is None:
                x3 = x3 if ok[0] else b["x_init"]
                x2 = x2 if ok[1] else b["x_init"]
                pp = pp if ok[2] else b["p_init"]
                pn = pn if ok[3] else b["p_init"]
            nf = [0.0 if k else 1.0 for k in ok]
        if self.par is None:     # first sample: initial state
            self.par = np.array([[pp, pn, x3, 0.0]] * 3)
            self.r7 = np.array([pn * (self.A * self.L - self.A * x3 + self.V0)
                                + pp * (self.A * x3 + self.V0), 0.0])
            self.r8 = np.array([pp, x3, 0.0])
            self.r9 = np.array([pn, x3, 0.0])
            self.kf4.x = np.array([[pp - pn], [x3], [0.0]])
            self.kf5.x = np.array([[pp - pn], [0.0]])
            self.kf6.x = np.array([[x3], [0.0]])
        if c["guards"]:
            # the position by the main model's, each pressure by its parity model's
            x3 = x3 if ok[0] else self.par[0, 2]
            x2 = x2 if ok[1] else self.par[0, 2]
            pp = pp if ok[2] else self.par[1, 0]
            pn = pn if ok[3] else self.par[2, 1]
        dp = pp - pn
        realign = self.flags == 0
        accommodate = self.action == 1
        dt = c["dt"]

        # parallel models (R1-R3), each realigned on its own residual (dedicated
        # realignment: R1 every state, R2 and R3 the pressures and xdot), RK4, clamping
        r123 = np.array([x3 - self.par[0, 2], pp - self.par[1, 0], pn - self.par[2, 1]])
        nxt = np.empty((3, 4))
        for i, (res, cols) in enumerate((("R1", [0, 1, 2, 3]), ("R2", [0, 1, 3]),
                                         ("R3", [0, 1, 3]))):
            s = self.par[i].copy()
            if realign:
                s[cols] += np.array(c["parity_gain"][res]) * r123[i]
            k1 = self._f(s, v)
            k2 = self._f(s + 0.5 * dt * k1, v)
            k3 = self._f(s + 0.5 * dt * k2, v)
            k4 = self._f(s + dt * k3, v)
            n = s + dt / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)
            n[0] = min(self.Psup, max(self.Patm, n[0]))
            n[1] = min(self.Psup, max(self.Patm, n[1]))
            n[2] = min(self.L, max(0.0, n[2]))
            nxt[i] = n

        # R7: valve-blind combination
        m_meas = pn * (self.A * self.L - self.A * x3 + self.V0) + pp * (self.A * x3 + self.V0)
        r7 = m_meas - self.r7[0]
        m = self.r7[0] + c["R7_gain"] * r7 if realign else self.r7[0]
        a7, b7, cm = self.A * dp / self.M, self.Ff / self.M, (1.0 - self.gamma) * self.A * dp
        xd = self.r7[1]
        q1 = a7 - b7 * xd
        xd2 = xd + 0.5 * dt * q1
        q2 = a7 - b7 * xd2
        xd3 = xd + 0.5 * dt * q2
        q3 = a7 - b7 * xd3
        xd4 = xd + dt * q3
        q4 = a7 - b7 * xd4
        r7_next = np.array([m + dt / 6.0 * cm * (xd + 2.0 * (xd2 + xd3) + xd4),
                            xd + dt / 6.0 * (q1 + 2.0 * (q2 + q3) + q4)])

        # R8, R9: one chamber simulated, the other measured, realigned on x3
        r8, r9 = x3 - self.r8[1], x3 - self.r9[1]
        s8 = self.r8 + np.array(c["R8_gain"]) * r8 if realign else self.r8
        s9 = self.r9 + np.array(c["R9_gain"]) * r9 if realign else self.r9
        r8_next = self._rk4_reduced(s8, v, pn, 0)
        r9_next = self._rk4_reduced(s9, v, pp, 1)

        # Kalman residuals (filterpy), voter
        x1 = float((self.kf4.H @ self.kf4.x)[0, 0])
        r4 = x3 - x1
        r5 = dp - float((self.kf5.H @ self.kf5.x)[0, 0])
        r6 = x3 - float((self.kf6.H @ self.kf6.x)[0, 0])
        inv = 1.0 / c["voter_tolerance"]
        d = np.array([x1, x2, x3]) * inv
        q12, q13, q23 = (d[0] - d[1]) ** 2, (d[0] - d[2]) ** 2, (d[1] - d[2]) ** 2
        w = 1.0 / (1.0 + np.array([q12 * q13, q12 * q23, q13 * q23]))
        wsum = w.sum()
        rw = np.maximum(0.0, 1.0 - 3.0 * w / wsum)
        voter_out = (w[0] * x1 + w[1] * x2 + w[2] * x3) / wsum
        fused = (w[1] * x2 + w[2] * x3) / (w[1] + w[2])
        self.kf4.update_steadystate(np.array([[fused]]))
        if c["sched"] is not None:
            self._schedule(pp, pn, voter_out)
        self.kf4.predict_steadystate(np.array([[v]]))
        self.kf5.update_steadystate(np.array([[dp]]))
        self.kf5.predict_steadystate(np.array([[v]]))
        self.kf6.update_steadystate(np.array([[x3]]))
        self.kf6.predict_steadystate(np.array([[v], [pp], [pn]]))
        self.par, self.r7, self.r8, self.r9 = nxt, r7_next, r8_next, r9_next

        # moving RMS (a non-finite square enters as 0 and reads as an infinite RMS),
        # latched flags, frozen horizon, isolation on the class-level flags
        r = np.array([r123[0], r123[1], r123[2], r4, r5, rw[0], rw[1], rw[2], r6, r7,
                      r8, r9] + nf)
        sq = r * r
        ok = sq <= c["sq_max"]
        sq = np.where(ok, sq, 0.0)
        self.sums = self.sums + sq - self.buf[self.index]
        self.buf[self.index] = sq
        self.index = (self.index + 1) % c["window"]
        rms = np.where(ok, np.sqrt(np.maximum(self.sums, 0.0) * (1.0 / c["window"])), np.inf)
        old = self.flags
        for i in np.flatnonzero(rms > self.thr):
            self.flags |= 1 << int(i)
        if old and self.frozen < 2 ** 31 - 1:
            self.frozen += 1
        for i, h in enumerate(c["horizons"]):
            if (self.flags & ~old) >> i & 1 and self.frozen > h:
                self.late |= 1 << i
        cflags = self.flags & c["class_flags"] & ~self.late
        classes = 0
        if cflags:
            for mask, cls in c["patterns"]:
                if cflags & ~mask == 0:
                    classes |= 1 << cls
        match, acand = c["class_of_mask"][classes], c["acand_of_mask"][classes]
        if match and match == self.candidate:
            self.count += 1
        else:
            self.count = 1 if match else 0
        self.candidate = match
        if acand and acand == self.action_candidate:
            self.action_count += 1
        else:
            self.action_count = 1 if acand else 0
        self.action_candidate = acand
        if self.decision == 0:
            contradicted = cflags != 0 and classes == 0
        else:
            contradicted = c["escalate"] and cflags & ~c["class_unions"][self.decision] != 0
        if contradicted:
            self.decision = len(c["class_unions"]) - 1
        elif self.decision == 0 and match and self.count >= c["confirm"]:
            self.decision = match
        taken = (acand if self.decision == 0
                 and self.action_count >= c["need_of_mask"][classes] else 0)
        self.action = max(self.action, c["action_codes"][self.decision], taken)
        return {"r": r, "rms": rms, "flags": self.flags, "fault_class": self.decision,
                "action": self.action,
                "aux": np.array([voter_out, voter_out if accommodate else x3])}

    def run(self, u, y) -> dict:
        self.reset()
        K = len(u)
        out = {"r": np.empty((K, self.nr)), "rms": np.empty((K, self.nr)),
               "flags": np.empty(K, dtype=np.int64), "fault_class": np.empty(K, dtype=np.int64),
               "action": np.empty(K, dtype=np.int64), "aux": np.empty((K, 2))}
        for k in range(K):
            res = self.step(u[k], y[k])
            for key in out:
                out[key][k] = res[key]
        return out
