/*
 * fdi_hand.h -- a hand-written C99 FDI step for the pneumatic cylinder: the performance
 * limit the generated core (generated/pneumatic_cylinder/c/pneumatic_cylinder_fdi.c) is
 * measured against by bench/run.py. NOT part of fdigen; not used by any product code.
 *
 * Same computation as the generated step (three parallel models RK4, each realigned on
 * its own parity residual -- dedicated realignment: par on R1, par_R2 on R2, par_R3 on
 * R3 --, R7's valve-blind parallel model, R8/R9's reduced parallel models (one chamber
 * simulated, the other measured), Kalman filters R4/R5/R6, Broen's voter, moving RMS
 * over a ring buffer that never lets a NaN or infinite residual into its sums (such a
 * sample reads as an infinite RMS), latched flags, the frozen-residual validity horizon
 * (a flag rising after its residual's horizon of frozen samples is not read by the class
 * decision), isolation on the class-level flags as bitmask operations on the flag word
 * and table look-ups by the mask of consistent classes, the action policy under
 * ambiguity (the most severe action, or a unanimous one, held for its own count), the
 * contradiction of the isolated class (escalate_after_isolation), the consistent-faults
 * mask, and the validation of the state (a running sum or a ring-buffer entry out of its
 * range, or a counter out of its range, reads an infinite RMS and returns 2), structured
 * as the design's program is (one block per part, in the same order, so that a change of
 * the design maps to one block here), written the way an engineer would write it by
 * hand: parameter-only subexpressions computed once in fdi_hand_init(), one division per
 * chamber and RK4 stage, matrix-vector products written out over the non-zero entries,
 * no helper calls. With FH_SCHED (R4 and R5 declared `schedule = "measured"`) the
 * prediction matrices of R4 and R5 are re-evaluated every sample at the voted position
 * and, for the filters whose schedule reads them (FH_R4_SCHED_P, FH_R5_SCHED_P), the
 * measured chamber pressures: the Jacobian entries share one division, 1/(Vp Vn), and
 * the discrete entries are affine in them (constants folded by
 * hand_schedule.schedule_constants). The constant gains come from fdi_hand_gains.h,
 * which bench/run.py writes from the design.json of the generated code it builds (and,
 * for the few constants design.json does not list -- the parity, R7, R8, R9 realignment
 * gains, the voter tolerance, the validity bounds, the horizons, SQ_MAX, the valid sum
 * range, the class tables of the action policy -- from the design object of the same
 * model; bench/hand_consts.py). With FH_GUARDS (designs whose residuals end with nf_x3,
 * nf_x2, nf_pp, nf_pn) invalid samples (|value| above a bound, or NaN) are replaced as
 * the generated core does (the position by par_x, the pressures by their own parity
 * model's, par_R2_Pp and par_R3_Pn) and flagged.
 */
#ifndef FDI_HAND_H
#define FDI_HAND_H

#include <stdint.h>

#include "fdi_hand_gains.h"

#define FDI_HAND_NZ 27       /* the generated layout: par 4, par_R2 4, par_R3 4, R7 2, R8 3,
                                R9 3, R4 3, R5 2, R6 2 */
#define FDI_HAND_NR FH_NR      /* 12, or 16 with the measurement-validity residuals */
#define FDI_HAND_NP 12
#define FDI_HAND_WINDOW FH_WINDOW

/* Parameters in model order, and what init derives from them. */
typedef struct {
    double gamma, R, Ts, A, M, Ff, L, V0, K, Psup, Patm, P0;
    /* derived once: */
    double gA;     /* gamma*A */
    double KRTg;   /* K*R*Ts*gamma */
    double A_M;    /* A/M */
    double Ff_M;   /* Ff/M */
    double ALV0;   /* A*L + V0 */
    double c7;     /* (1 - gamma)*A: dm/dt = c7 (pp - pn) xdot */
    double KRTgS;  /* K*R*Ts*gamma*(A*L + 2*V0): the valve gain's numerator, Vp + Vn */
    double gAPS;   /* -A*gamma*P0*(A*L + 2*V0): the stiffness's numerator at the operating
                      point's pressures (P0 in both chambers) */
} fdi_hand_params;

typedef struct {
    double z[FDI_HAND_NZ];  /* same layout as the generated state */
    double buf[FDI_HAND_WINDOW][FDI_HAND_NR];
    double sums[FDI_HAND_NR];
    int32_t index;
    uint32_t flags;
    int32_t candidate, count, decision, initialised;
    int32_t frozen;         /* samples run with the realignment frozen (saturating) */
    uint32_t late;          /* flags risen after their residual's frozen horizon */
    int32_t action_candidate, action_count;   /* the action the consistent classes call
                                                 for, and the samples it held */
    int32_t action;         /* latched action code (never decreases) */
} fdi_hand_state;

typedef struct {
    double r[FDI_HAND_NR];
    double rms[FDI_HAND_NR];
    uint32_t flags;
    int32_t fault_class;
    int32_t action;
    double aux[2];          /* voter_out, position_for_control */
    uint32_t faults;        /* faults consistent with the flags (0: no flag) */
} fdi_hand_output;

/* Derive the parameter constants from p (model order) and reset the state. */
void fdi_hand_init(fdi_hand_state *st, fdi_hand_params *P, const double p[FDI_HAND_NP]);

/* One sample. Returns 0, 1 if a state or residual is not finite, 2 if the state was
   corrupted (as the generated). */
int fdi_hand_step(fdi_hand_state *st, const fdi_hand_params *P, const double u[1],
                  const double y[4], fdi_hand_output *out);

#endif
