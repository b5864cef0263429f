/*
 * A controller that embeds the generated FDI core of the pneumatic cylinder.
 *
 * It reads a log in the rig format (t,u,x,x2,pp,pn[,xref]) from stdin, as if the samples
 * arrived from the I/O of a real-time task, and at each sample:
 *   1. runs pneumatic_cylinder_fdi_step() on the valve command and the four sensors;
 *   2. takes the position used for control from the FDI (the primary sensor, or the
 *      voter's output once a position sensor fault is accommodated);
 *   3. computes the rig's position law u = clip(40 (xref - x), -5, 5), or 0 V once the
 *      isolated fault asks for a safety stop.
 * It prints one line per flag raised and per decision, then a summary line.
 *
 * Build: make (see Makefile), with -std=c99 -Wall -Wextra -Werror -pedantic.
 */
#include <stdio.h>
#include <string.h>

#include "pneumatic_cylinder_fdi.h"

typedef pneumatic_cylinder_real real;

static real clip(real v, real lo, real hi)
{
    return v < lo ? lo : (v > hi ? hi : v);
}

int main(void)
{
    pneumatic_cylinder_fdi_params params;
    pneumatic_cylinder_fdi_state state;
    pneumatic_cylinder_fdi_output out;
    char line[512];
    uint32_t reported = 0u;
    int32_t decision = 0;
    long k = 0;
    int status, have_ref = 0;
    double t, u, x, x2, pp, pn, xref = 0.0, u_next = 0.0;

    pneumatic_cylinder_fdi_default_params(&params);
    status = pneumatic_cylinder_fdi_init(&state, &params);
    if (status != PNEUMATIC_CYLINDER_FDI_OK) {
        fprintf(stderr, "fdi init failed: %d\n", status);
        return 1;
    }
    if (fgets(line, sizeof line, stdin) == NULL) {
        fprintf(stderr, "empty input\n");
        return 1;
    }
    have_ref = strstr(line, "xref") != NULL;
    while (fgets(line, sizeof line, stdin) != NULL) {
        real uu[PNEUMATIC_CYLINDER_FDI_NU];
        real yy[PNEUMATIC_CYLINDER_FDI_NY];
        int n = sscanf(line, "%lf,%lf,%lf,%lf,%lf,%lf,%lf", &t, &u, &x, &x2, &pp, &pn, &xref);
        if (n < 6) {
            continue;
        }
        uu[0] = (real)u;            /* the command that was sent at this sample */
        yy[0] = (real)x;            /* x3: primary position sensor */
        yy[1] = (real)x2;           /* redundant position sensor */
        yy[2] = (real)pp;
        yy[3] = (real)pn;
        status = pneumatic_cylinder_fdi_step(&state, &params, uu, yy, &out);
        if (status < 0) {
            fprintf(stderr, "fdi step failed at sample %ld: %d\n", k, status);
            return 1;
        }
        {
            int i;
            for (i = 0; i < PNEUMATIC_CYLINDER_FDI_NR; ++i) {
                uint32_t bit = (uint32_t)1 << i;
                if ((out.flags & bit) && !(reported & bit)) {
                    printf("flag %s %.4f\n", pneumatic_cylinder_fdi_residual_names[i], t);
                    reported |= bit;
                }
            }
        }
        if (out.fault_class != decision) {
            decision = out.fault_class;
            printf("decision %s %s %.4f\n", pneumatic_cylinder_fdi_class_names[decision],
                   pneumatic_cylinder_fdi_action_names[out.action], t);
        }
        /* the command for the next sample: position from the FDI (accommodated) */
        if (have_ref && n >= 7) {
            real pos = out.aux[1]; /* position_for_control */
            u_next = out.action == 2 ? 0.0 : clip((real)(40.0 * (xref - pos)), -5.0, 5.0);
        }
        ++k;
    }
    printf("summary samples=%ld class=%s action=%s flags=%lu last_command=%.4f\n", k,
           pneumatic_cylinder_fdi_class_names[decision],
           pneumatic_cylinder_fdi_action_names[decision == 0 ? 0 : out.action],
           (unsigned long)out.flags, u_next);
    return 0;
}
