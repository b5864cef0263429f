/*
 * fdi_hand.c -- hand-written FDI step of the pneumatic cylinder (see fdi_hand.h).
 * Benchmark baseline only: bench/run.py checks it against the generated step on the rig
 * logs (residuals to 1e-12 of their scale, identical flags, class and action) and then
 * times both with the same compiler flags.
 */
#include "fdi_hand.h"

#include <math.h>
#include <string.h>

void fdi_hand_init(fdi_hand_state *st, fdi_hand_params *P, const double p[FDI_HAND_NP])
{
    P->gamma = p[0]; P->R = p[1]; P->Ts = p[2]; P->A = p[3]; P->M = p[4]; P->Ff = p[5];
    P->L = p[6]; P->V0 = p[7]; P->K = p[8]; P->Psup = p[9]; P->Patm = p[10]; P->P0 = p[11];
    P->gA = P->gamma * P->A;
    P->KRTg = P->K * P->R * P->Ts * P->gamma;
    P->A_M = P->A / P->M;
    P->Ff_M = P->Ff / P->M;
    P->ALV0 = P->A * P->L + P->V0;
    P->c7 = (1.0 - P->gamma) * P->A;
    P->KRTgS = P->KRTg * (P->A * P->L + 2.0 * P->V0);
#if FH_SCHED
    P->gAPS = -P->gA * FH_S_OP_P * (P->A * P->L + 2.0 * P->V0);
#else
    P->gAPS = 0.0;
#endif
    memset(st, 0, sizeof *st);   /* frozen = 0, late = 0 */
}

/* Right-hand side of the cylinder model (eqs 1-3), kgv = K R Ts gamma v. */
#define PAR_RHS(k, Pp, Pn, x, xd)                                  \
    do {                                                          \
        const double Vp_ = P->A * (x) + P->V0;                    \
        const double Vn_ = P->ALV0 - P->A * (x);                  \
        k[0] = (kgv - P->gA * (Pp) * (xd)) / Vp_;                 \
        k[1] = (P->gA * (Pn) * (xd) - kgv) / Vn_;                 \
        k[2] = (xd);                                              \
        k[3] = P->A_M * ((Pp) - (Pn)) - P->Ff_M * (xd);           \
    } while (0)

/* One RK4 step of the cylinder model from c (Pp, Pn, x, xdot) into zn[o..o+3], the
   pressures clamped to [Patm, Psup], the position to [0, L]. */
#define PAR_RK4(c, o)                                                                   \
    do {                                                                                \
        double k1[4], k2[4], k3[4], k4[4];                                              \
        PAR_RHS(k1, c[0], c[1], c[2], c[3]);                                            \
        PAR_RHS(k2, c[0] + h2 * k1[0], c[1] + h2 * k1[1], c[2] + h2 * k1[2],            \
                c[3] + h2 * k1[3]);                                                     \
        PAR_RHS(k3, c[0] + h2 * k2[0], c[1] + h2 * k2[1], c[2] + h2 * k2[2],            \
                c[3] + h2 * k2[3]);                                                     \
        PAR_RHS(k4, c[0] + FH_DT * k3[0], c[1] + FH_DT * k3[1], c[2] + FH_DT * k3[2],   \
                c[3] + FH_DT * k3[3]);                                                  \
        const double n0 = c[0] + h6 * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0]);          \
        const double n1 = c[1] + h6 * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1]);          \
        const double n2 = c[2] + h6 * (k1[2] + 2.0 * (k2[2] + k3[2]) + k4[2]);          \
        zn[(o) + 3] = c[3] + h6 * (k1[3] + 2.0 * (k2[3] + k3[3]) + k4[3]);              \
        zn[(o)] = n0 < P->Patm ? P->Patm : (n0 > P->Psup ? P->Psup : n0);                \
        zn[(o) + 1] = n1 < P->Patm ? P->Patm : (n1 > P->Psup ? P->Psup : n1);            \
        zn[(o) + 2] = n2 < 0.0 ? 0.0 : (n2 > P->L ? P->L : n2);                          \
    } while (0)

int fdi_hand_step(fdi_hand_state *st, const fdi_hand_params *P, const double u[1],
                  const double y[4], fdi_hand_output *out)
{
    double *z = st->z;
    double zn[FDI_HAND_NZ];
    double chk = 0.0;
    int i;
#if FH_GUARDS
    /* measurement validity: |value| <= bound (false for NaN), else a substitute: the
       position by the main parallel model's, each pressure by its parity model's */
    const int ok_v = fabs(u[0]) <= FH_BOUND_V;
    const int ok_x3 = fabs(y[0]) <= FH_BOUND_X, ok_x2 = fabs(y[1]) <= FH_BOUND_X;
    const int ok_pp = fabs(y[2]) <= FH_BOUND_P, ok_pn = fabs(y[3]) <= FH_BOUND_P;
    const double v = ok_v ? u[0] : FH_FALLBACK_V;
    if (!st->initialised) {        /* invalid first sample: the operating point's outputs */
        z[2] = ok_x3 ? y[0] : FH_INIT_X;
        z[4] = ok_pp ? y[2] : FH_INIT_P;
        z[9] = ok_pn ? y[3] : FH_INIT_P;
    }
    const double x3 = ok_x3 ? y[0] : z[2], x2 = ok_x2 ? y[1] : z[2];
    const double pp = ok_pp ? y[2] : z[4], pn = ok_pn ? y[3] : z[9];
#else
    const double v = u[0], x3 = y[0], x2 = y[1], pp = y[2], pn = y[3];
#endif
    const double dp = pp - pn;

    if (!st->initialised) {
        z[0] = pp; z[1] = pn; z[2] = x3; z[3] = 0.0;     /* par: Pp, Pn, x, xdot */
        z[4] = pp; z[5] = pn; z[6] = x3; z[7] = 0.0;     /* par_R2 */
        z[8] = pp; z[9] = pn; z[10] = x3; z[11] = 0.0;   /* par_R3 */
        z[12] = pn * (P->ALV0 - P->A * x3) + pp * (P->A * x3 + P->V0);
        z[13] = 0.0;
        z[14] = pp; z[15] = x3; z[16] = 0.0;         /* R8: Pp, x, xdot */
        z[17] = pn; z[18] = x3; z[19] = 0.0;         /* R9: Pn, x, xdot */
        z[20] = dp; z[21] = x3; z[22] = 0.0;         /* R4: Pd, x, xdot */
        z[23] = dp; z[24] = 0.0;                     /* R5: Pd, xdot */
        z[25] = x3; z[26] = 0.0;                     /* R6: x, xdot */
        st->initialised = 1;
    }
    const int realign = st->flags == 0u;
    const int accommodate = st->action == 1;   /* the latched action says accommodate */
    const double kgv = P->KRTg * v;
    const double h2 = 0.5 * FH_DT, h6 = FH_DT / 6.0;

    /* -- R1-R3: three parallel models, each realigned (until a flag is up) on its own
       parity residual (dedicated realignment), RK4, clamped -- */
    const double r1 = x3 - z[2], r2 = pp - z[4], r3 = pn - z[9];
    {
        double c[4];
        if (realign) {                     /* par on R1: every state */
            c[0] = z[0] + FH_R1_G_Pp * r1; c[1] = z[1] + FH_R1_G_Pn * r1;
            c[2] = z[2] + FH_R1_G_x * r1; c[3] = z[3] + FH_R1_G_xdot * r1;
        } else {
            c[0] = z[0]; c[1] = z[1]; c[2] = z[2]; c[3] = z[3];
        }
        PAR_RK4(c, 0);
        /* par_R2 on R2, par_R3 on R3: the pressures and xdot (x is not realigned) */
#define PARITY_REALIGN(o, r, G)                                                         \
        do {                                                                            \
            c[0] = z[(o)]; c[1] = z[(o) + 1]; c[2] = z[(o) + 2]; c[3] = z[(o) + 3];     \
            if (realign) {                                                              \
                c[0] += G##_G_Pp * (r); c[1] += G##_G_Pn * (r); c[3] += G##_G_xdot * (r);\
            }                                                                           \
        } while (0)
        PARITY_REALIGN(4, r2, FH_R2);
        PAR_RK4(c, 4);
        PARITY_REALIGN(8, r3, FH_R3);
        PAR_RK4(c, 8);
#undef PARITY_REALIGN
    }

    /* -- R7: m = Vp pp + Vn pn (blind to the valve) and xdot, driven by pp, pn, x3 -- */
    const double Ax3 = P->A * x3;
    const double r7 = pn * (P->ALV0 - Ax3) + pp * (Ax3 + P->V0) - z[12];
    {
        const double m = realign ? z[12] + FH_R7_G * r7 : z[12];
        const double cm = P->c7 * dp;              /* dm/dt = cm * xdot */
        const double a7 = P->A_M * dp;             /* dxdot/dt = a7 - Ff/M xdot */
        const double xd1 = z[13];
        const double k1 = a7 - P->Ff_M * xd1;
        const double xd2 = xd1 + 0.5 * FH_DT * k1;
        const double k2 = a7 - P->Ff_M * xd2;
        const double xd3 = xd1 + 0.5 * FH_DT * k2;
        const double k3 = a7 - P->Ff_M * xd3;
        const double xd4 = xd1 + FH_DT * k3;
        const double k4 = a7 - P->Ff_M * xd4;
        zn[12] = m + h6 * cm * (xd1 + 2.0 * (xd2 + xd3) + xd4);
        zn[13] = xd1 + h6 * (k1 + 2.0 * (k2 + k3) + k4);
    }

    /* -- R8, R9: one chamber, x and xdot simulated, the other chamber's pressure
       measured; realigned on x3 (until a flag is up), RK4, clamped -- */
    const double r8 = x3 - z[15], r9 = x3 - z[18];
    {
        double c8[3], c9[3], k1[3], k2[3], k3[3], k4[3];
        if (realign) {
            c8[0] = z[14] + FH_R8_G0 * r8; c8[1] = z[15] + FH_R8_G1 * r8;
            c8[2] = z[16] + FH_R8_G2 * r8;
            c9[0] = z[17] + FH_R9_G0 * r9; c9[1] = z[18] + FH_R9_G1 * r9;
            c9[2] = z[19] + FH_R9_G2 * r9;
        } else {
            c8[0] = z[14]; c8[1] = z[15]; c8[2] = z[16];
            c9[0] = z[17]; c9[1] = z[18]; c9[2] = z[19];
        }
        /* R8: Pp' = (kgv - gA Pp xd)/Vp, x' = xd, xd' = A/M (Pp - pn) - Ff/M xd */
#define R8_RHS(k, Pp_, x_, xd_)                                                 \
        do {                                                                   \
            k[0] = (kgv - P->gA * (Pp_) * (xd_)) / (P->A * (x_) + P->V0);      \
            k[1] = (xd_);                                                      \
            k[2] = P->A_M * ((Pp_) - pn) - P->Ff_M * (xd_);                    \
        } while (0)
        R8_RHS(k1, c8[0], c8[1], c8[2]);
        R8_RHS(k2, c8[0] + h2 * k1[0], c8[1] + h2 * k1[1], c8[2] + h2 * k1[2]);
        R8_RHS(k3, c8[0] + h2 * k2[0], c8[1] + h2 * k2[1], c8[2] + h2 * k2[2]);
        R8_RHS(k4, c8[0] + FH_DT * k3[0], c8[1] + FH_DT * k3[1], c8[2] + FH_DT * k3[2]);
#undef R8_RHS
        {
            const double n0 = c8[0] + h6 * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0]);
            const double n1 = c8[1] + h6 * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1]);
            zn[16] = c8[2] + h6 * (k1[2] + 2.0 * (k2[2] + k3[2]) + k4[2]);
            zn[14] = n0 < P->Patm ? P->Patm : (n0 > P->Psup ? P->Psup : n0);
            zn[15] = n1 < 0.0 ? 0.0 : (n1 > P->L ? P->L : n1);
        }
        /* R9: Pn' = (gA Pn xd - kgv)/Vn, x' = xd, xd' = A/M (pp - Pn) - Ff/M xd */
#define R9_RHS(k, Pn_, x_, xd_)                                                 \
        do {                                                                   \
            k[0] = (P->gA * (Pn_) * (xd_) - kgv) / (P->ALV0 - P->A * (x_));    \
            k[1] = (xd_);                                                      \
            k[2] = P->A_M * (pp - (Pn_)) - P->Ff_M * (xd_);                    \
        } while (0)
        R9_RHS(k1, c9[0], c9[1], c9[2]);
        R9_RHS(k2, c9[0] + h2 * k1[0], c9[1] + h2 * k1[1], c9[2] + h2 * k1[2]);
        R9_RHS(k3, c9[0] + h2 * k2[0], c9[1] + h2 * k2[1], c9[2] + h2 * k2[2]);
        R9_RHS(k4, c9[0] + FH_DT * k3[0], c9[1] + FH_DT * k3[1], c9[2] + FH_DT * k3[2]);
#undef R9_RHS
        {
            const double n0 = c9[0] + h6 * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0]);
            const double n1 = c9[1] + h6 * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1]);
            zn[19] = c9[2] + h6 * (k1[2] + 2.0 * (k2[2] + k3[2]) + k4[2]);
            zn[17] = n0 < P->Patm ? P->Patm : (n0 > P->Psup ? P->Psup : n0);
            zn[18] = n1 < 0.0 ? 0.0 : (n1 > P->L ? P->L : n1);
        }
    }

    /* -- Kalman residuals (prediction z = x(k|k-1)) -- */
    const double x1 = z[21];                     /* R4's position estimate */
    const double r4 = x3 - x1;
    const double r5 = dp - z[23];
    const double r6 = x3 - z[25];

    /* -- Broen's voter over x1 (R4 estimate), x2 (redundant), x3 (primary) -- */
    /* scaled first, then subtracted (as the generated core: the same three products) */
    const double s1 = x1 * FH_VINV, s2 = x2 * FH_VINV, s3 = x3 * FH_VINV;
    const double d12 = s1 - s2, d13 = s1 - s3, d23 = s2 - s3;
    const double q12 = d12 * d12, q13 = d13 * d13, q23 = d23 * d23;
    const double w1 = 1.0 / (1.0 + q12 * q13);
    const double w2 = 1.0 / (1.0 + q12 * q23);
    const double w3 = 1.0 / (1.0 + q13 * q23);
    const double isum = 1.0 / (w1 + w2 + w3);
    double rw1 = 1.0 - 3.0 * w1 * isum, rw2 = 1.0 - 3.0 * w2 * isum, rw3 = 1.0 - 3.0 * w3 * isum;
    rw1 = rw1 < 0.0 ? 0.0 : rw1;
    rw2 = rw2 < 0.0 ? 0.0 : rw2;
    rw3 = rw3 < 0.0 ? 0.0 : rw3;
    const double w2x2 = w2 * x2, w3x3 = w3 * x3;
    const double voter_out = (w1 * x1 + w2x2 + w3x3) * isum;
    const double fused = (w2x2 + w3x3) / (w2 + w3);

    /* -- prediction matrices of R4 and R5 (the same reduced model, R5 without x) -- */
#if FH_SCHED
    /* scheduled on the voted position (and, per filter, the measured pressures), clamped
       to their limits: a = dPd'/dxdot = -A gamma (Pp/Vp + Pn/Vn), b = dPd'/dv =
       K R Ts gamma (1/Vp + 1/Vn); one division, 1/(Vp Vn), for all of them. The
       discrete entries are affine in a and b (C + G a; hand_schedule.schedule_constants). */
    const double sx = voter_out < 0.0 ? 0.0 : (voter_out > P->L ? P->L : voter_out);
    const double sVp = P->A * sx + P->V0, sVn = P->ALV0 - P->A * sx;
    const double iVV = 1.0 / (sVp * sVn);
    const double sb = P->KRTgS * iVV;
    const double Bd0 = FH_S_B0 + FH_S_HB0 * sb, Bd2 = FH_S_B2 + FH_S_HB2 * sb;
#if FH_R4_SCHED_P || FH_R5_SCHED_P
    const double sPp = pp < P->Patm ? P->Patm : (pp > P->Psup ? P->Psup : pp);
    const double sPn = pn < P->Patm ? P->Patm : (pn > P->Psup ? P->Psup : pn);
    const double a_meas = -P->gA * (sPp * sVn + sPn * sVp) * iVV;
#endif
#if !FH_R4_SCHED_P || !FH_R5_SCHED_P
    const double a_op = P->gAPS * iVV;          /* pressures at the operating point */
#endif
#if FH_R4_SCHED_P
    const double a4 = a_meas;
#else
    const double a4 = a_op;
#endif
#if FH_R5_SCHED_P
    const double a5 = a_meas;
#else
    const double a5 = a_op;
#endif
    const double ga4 = FH_S_GA0 * a4, ga5 = FH_S_GA0 * a5;
    const double R4a00 = FH_S_A00 + ga4, R4a02 = FH_S_A02 + FH_S_GA02 * a4;
    const double R4a22 = FH_S_A22 + ga4;
    const double R5a00 = FH_S_A00 + ga5, R5a01 = FH_S_A02 + FH_S_GA02 * a5;
    const double R5a11 = FH_S_A22 + ga5;
    const double R4b0 = Bd0, R4b2 = Bd2, R5b0 = Bd0, R5b1 = Bd2;
#else
    const double R4a00 = FH_R4_A00, R4a02 = FH_R4_A02, R4a22 = FH_R4_A22;
    const double R5a00 = FH_R5_A00, R5a01 = FH_R5_A01, R5a11 = FH_R5_A11;
    const double R4b0 = FH_R4_B0, R4b2 = FH_R4_B2, R5b0 = FH_R5_B0, R5b1 = FH_R5_B1;
#endif

    /* -- filter updates (x+ = x + M e) and predictions (x' = A x+ + B u) -- */
    {
        const double e = fused - x1;             /* R4 is updated with the voter's fusion */
        const double a = z[20] + FH_R4_M0 * e, b = z[21] + FH_R4_M1 * e;
        const double d = z[22] + FH_R4_M2 * e;
        zn[20] = R4a00 * a + R4a02 * d + R4b0 * v;
        zn[21] = FH_R4_A10 * a + b + FH_R4_A12 * d + FH_R4_B1 * v;
        zn[22] = FH_R4_A20 * a + R4a22 * d + R4b2 * v;
    }
    {
        const double a = z[23] + FH_R5_M0 * r5, b = z[24] + FH_R5_M1 * r5;
        zn[23] = R5a00 * a + R5a01 * b + R5b0 * v;
        zn[24] = FH_R5_A10 * a + R5a11 * b + R5b1 * v;
    }
    {
        const double a = z[25] + FH_R6_M0 * r6, b = z[26] + FH_R6_M1 * r6;
        zn[25] = a + FH_R6_A01 * b + FH_R6_BP0 * dp;
        zn[26] = FH_R6_A11 * b + FH_R6_BP1 * dp;
    }

    out->r[0] = r1; out->r[1] = r2; out->r[2] = r3; out->r[3] = r4; out->r[4] = r5;
    out->r[5] = rw1; out->r[6] = rw2; out->r[7] = rw3; out->r[8] = r6; out->r[9] = r7;
    out->r[10] = r8; out->r[11] = r9;
#if FH_GUARDS
    out->r[12] = ok_x3 ? 0.0 : 1.0; out->r[13] = ok_x2 ? 0.0 : 1.0;
    out->r[14] = ok_pp ? 0.0 : 1.0; out->r[15] = ok_pn ? 0.0 : 1.0;
#endif
    out->aux[0] = voter_out;
    out->aux[1] = accommodate ? voter_out : x3;
    for (i = 0; i < FDI_HAND_NZ; ++i) {
        z[i] = zn[i];
        chk += zn[i] - zn[i];                    /* NaN iff some value is Inf or NaN */
    }

    /* -- moving RMS (ring buffer, running sums), latched flags. A residual whose square
       is not finite (or above SQ_MAX) enters the window as 0 and reads as an infinite
       RMS: its flag rises, the sums stay finite. State validation: a counter or flag word
       out of its range corrupts every residual, a running sum outside [SUM_MIN, SUM_MAX]
       or a leaving buffer entry outside [0, SQ_MAX] (NaN fails both) its own; a
       corrupted residual reads an infinite RMS -- */
    const uint32_t old_flags = st->flags;
    const int state_bad = (st->count < 0) | (st->frozen < 0) | (st->action_count < 0)
                          | ((old_flags & ~FH_ALL_FLAGS) != 0u)
                          | ((st->late & ~FH_ALL_FLAGS) != 0u);
    int corrupt = state_bad;
    uint32_t flags = old_flags;
    {
        double *row = st->buf[st->index];
        for (i = 0; i < FDI_HAND_NR; ++i) {
            const double ri = out->r[i];
            const double sq = ri * ri, old = row[i], s0 = st->sums[i];
            const int ok = sq <= FH_SQ_MAX;     /* false for NaN and infinity */
            const int valid = (s0 >= FH_SUM_MIN) & (s0 <= FH_SUM_MAX) & (old >= 0.0)
                              & (old <= FH_SQ_MAX);
            const double sq_in = ok ? sq : 0.0;
            const double s = s0 + sq_in - old;
            chk += ri - ri;
            corrupt |= !valid;
            st->sums[i] = s;
            row[i] = sq_in;
            out->rms[i] = ok & valid & !state_bad
                ? sqrt((s > 0.0 ? s : 0.0) * (1.0 / FDI_HAND_WINDOW)) : INFINITY;
            flags |= (uint32_t)(out->rms[i] > FH_THRESHOLD[i]) << i;
        }
        st->flags = flags;
        st->index = st->index + 1 < FDI_HAND_WINDOW ? st->index + 1 : 0;
    }

    /* -- frozen horizon: a flag rising after its residual's horizon of samples run with
       the realignment frozen is late (not evidence) -- */
    if (old_flags != 0u && st->frozen < INT32_MAX) {
        st->frozen += 1;
    }
    {
        const uint32_t risen = flags & ~old_flags & FH_HORIZON_MASK;
        if (risen != 0u) {
            for (i = 0; i < FDI_HAND_NR; ++i) {
                if (((risen >> i) & 1u) && st->frozen > FH_HORIZON[i]) {
                    st->late |= 1u << i;
                }
            }
        }
    }

    /* -- isolation on the flag word: the mask of the classes of the patterns consistent
       with the class-level evidence (none while no such flag is up); the class (the only
       one), the action candidate and the samples it must hold, looked up by that mask;
       CONFIRM samples for the class -- */
    const uint32_t evidence = flags & ~st->late;
    const uint32_t cflags = evidence & FH_CLASS_FLAGS;
    uint32_t classes = 0u;
    if (cflags != 0u) {
        for (i = 0; i < FH_NPATTERNS; ++i) {
            classes |= (uint32_t)((cflags & ~FH_PATTERN_MASK[i]) == 0u) << FH_PATTERN_CLASS[i];
        }
    }
    const int32_t match = FH_CLASS_OF_MASK[classes];
    const int32_t acand = FH_ACAND_OF_MASK[classes];
    if (match != 0 && match == st->candidate) {
        st->count += st->count < INT32_MAX;
    } else {
        st->count = match != 0;
    }
    st->candidate = match;

    /* -- action policy (held for its own count) and contradiction: flags no declared
       fault explains (none isolated), or with FH_ESCALATE a flag outside the isolated
       class's union, make the decision unexplained -- */
    if (acand != 0 && acand == st->action_candidate) {
        st->action_count += st->action_count < INT32_MAX;
    } else {
        st->action_count = acand != 0;
    }
    st->action_candidate = acand;
    {
        const int contradicted = st->decision == 0
            ? cflags != 0u && classes == 0u
            : FH_ESCALATE && (cflags & ~FH_CLASS_UNION[st->decision]) != 0u;
        if (contradicted) {
            st->decision = FH_NCLASSES - 1;
        } else if (st->decision == 0 && match != 0 && st->count >= FH_CONFIRM) {
            st->decision = match;
        }
    }
    {
        const int32_t taken = st->decision == 0 && st->action_count >= FH_NEED_OF_MASK[classes]
                              ? acand : 0;
        int32_t act = FH_ACTION_CODE[st->decision];
        act = taken > act ? taken : act;
        st->action = act > st->action ? act : st->action;
    }

    /* -- consistent faults: those whose signature holds every flag of the evidence -- */
    {
        uint32_t faults = 0u;
        if (evidence != 0u) {
            for (i = 0; i < FH_NFAULTS; ++i) {
                faults |= (uint32_t)((evidence & ~FH_FAULT_MASK[i]) == 0u) << i;
            }
        }
        out->faults = faults;
    }
    out->flags = flags;
    out->fault_class = st->decision;
    out->action = st->action;
    return corrupt ? 2 : (chk == 0.0 ? 0 : 1);
}
