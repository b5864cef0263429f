/*
 * platform_driver.c -- bench driver: the six-leg platform step vs one leg's step.
 *
 *   platform_driver time LOG REPEATS   REPEATS x (one-leg pass, platform pass), interleaved;
 *                                      lines "<leg|platform> <wall ns/sample> <cpu ns/sample>"
 *   platform_driver count LOG          one pass of each (callgrind: loop_leg, loop_platform)
 *
 * With -DHAVE_PLATFORM=1 the platform pass calls the generated
 * pneumatic_cylinder_platform_set_demand + _step (six legs and the supervisor); without
 * it, six sequential pneumatic_cylinder_fdi_step calls on six leg states. Leg i reads the
 * log shifted by i * K / 6 samples (six different healthy trajectories); the leg inputs
 * are laid out [K][6][.] beforehand, so neither pass copies samples.
 */
#define _POSIX_C_SOURCE 200809L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "pneumatic_cylinder_fdi.h"
#ifdef HAVE_PLATFORM
#include "pneumatic_cylinder_platform_fdi.h"
#endif

#define NLEGS 6
static long K;
static double *U, *Y, *U6, *Y6, *D6;
static volatile double sink;

static void read_log(const char *path)
{
    FILE *f = fopen(path, "rb");
    int64_t k;
    long i, j, m;
    if (f == NULL || fread(&k, sizeof k, 1, f) != 1) {
        fprintf(stderr, "cannot read %s\n", path);
        exit(2);
    }
    K = (long)k;
    U = malloc(sizeof(double) * (size_t)K);
    Y = malloc(sizeof(double) * 4 * (size_t)K);
    if (fread(U, sizeof(double), (size_t)K, f) != (size_t)K
        || fread(Y, sizeof(double), 4 * (size_t)K, f) != 4 * (size_t)K) {
        fprintf(stderr, "short log %s\n", path);
        exit(2);
    }
    fclose(f);
    U6 = malloc(sizeof(double) * NLEGS * (size_t)K);
    Y6 = malloc(sizeof(double) * 4 * NLEGS * (size_t)K);
    D6 = malloc(sizeof(double) * NLEGS * (size_t)K);
    for (i = 0; i < K; ++i) {
        for (j = 0; j < NLEGS; ++j) {
            const long s = (i + j * (K / NLEGS)) % K;
            U6[i * NLEGS + j] = U[s];
            for (m = 0; m < 4; ++m) {
                Y6[(i * NLEGS + j) * 4 + m] = Y[s * 4 + m];
            }
            D6[i * NLEGS + j] = Y[s * 4];
        }
    }
}

static pneumatic_cylinder_fdi_params lp;
static pneumatic_cylinder_fdi_state ls;
#ifdef HAVE_PLATFORM
static pneumatic_cylinder_platform_params pp;
static pneumatic_cylinder_platform_state ps;
static pneumatic_cylinder_platform_output pout;
#else
static pneumatic_cylinder_fdi_state legs[NLEGS];
#endif

static void init_leg(void)
{
    pneumatic_cylinder_fdi_default_params(&lp);
    if (pneumatic_cylinder_fdi_init(&ls, &lp) != 0) {
        exit(3);
    }
}

static void init_platform(void)
{
#ifdef HAVE_PLATFORM
    pneumatic_cylinder_platform_default_params(&pp);
    if (pneumatic_cylinder_platform_init(&ps, &pp) != 0) {
        exit(3);
    }
#else
    int j;
    pneumatic_cylinder_fdi_default_params(&lp);
    for (j = 0; j < NLEGS; ++j) {
        if (pneumatic_cylinder_fdi_init(&legs[j], &lp) != 0) {
            exit(3);
        }
    }
#endif
}

__attribute__((noinline)) static double loop_leg(void)
{
    pneumatic_cylinder_fdi_output out;
    double acc = 0.0;
    long k;
    for (k = 0; k < K; ++k) {
        pneumatic_cylinder_fdi_step(&ls, &lp, U + k, Y + 4 * k, &out);
        acc += out.rms[0];
    }
    return acc;
}

__attribute__((noinline)) static double loop_platform(void)
{
    double acc = 0.0;
    long k;
#ifdef HAVE_PLATFORM
    for (k = 0; k < K; ++k) {
        pneumatic_cylinder_platform_set_demand(&ps, D6 + k * NLEGS);
        pneumatic_cylinder_platform_step(&ps, &pp,
            (const double (*)[PNEUMATIC_CYLINDER_PLATFORM_NU])(U6 + k * NLEGS),
            (const double (*)[PNEUMATIC_CYLINDER_PLATFORM_NY])(Y6 + k * NLEGS * 4), &pout);
        acc += pout.leg[0].rms[0];
    }
#else
    pneumatic_cylinder_fdi_output out;
    int j;
    for (k = 0; k < K; ++k) {
        for (j = 0; j < NLEGS; ++j) {
            pneumatic_cylinder_fdi_step(&legs[j], &lp, U6 + k * NLEGS + j,
                                        Y6 + (k * NLEGS + j) * 4, &out);
            acc += out.rms[0];
        }
    }
#endif
    return acc;
}

static double ns(clockid_t id)
{
    struct timespec t;
    clock_gettime(id, &t);
    return (double)t.tv_sec * 1e9 + (double)t.tv_nsec;
}

static void timed(const char *name, void (*init)(void), double (*loop)(void))
{
    double w0, c0, w1, c1;
    init();
    w0 = ns(CLOCK_MONOTONIC);
    c0 = ns(CLOCK_THREAD_CPUTIME_ID);
    sink = loop();
    c1 = ns(CLOCK_THREAD_CPUTIME_ID);
    w1 = ns(CLOCK_MONOTONIC);
    printf("%s %.4f %.4f\n", name, (w1 - w0) / (double)K, (c1 - c0) / (double)K);
}

int main(int argc, char **argv)
{
    if (argc >= 4 && strcmp(argv[1], "time") == 0) {
        int r, repeats = atoi(argv[3]);
        read_log(argv[2]);
        timed("leg", init_leg, loop_leg);
        timed("platform", init_platform, loop_platform);
        printf("--\n");
        for (r = 0; r < repeats; ++r) {
            if (r % 2 == 0) {
                timed("leg", init_leg, loop_leg);
                timed("platform", init_platform, loop_platform);
            } else {
                timed("platform", init_platform, loop_platform);
                timed("leg", init_leg, loop_leg);
            }
        }
    } else if (argc >= 3 && strcmp(argv[1], "count") == 0) {
        read_log(argv[2]);
        init_leg();
        sink = loop_leg();
        init_platform();
        sink = loop_platform();
    } else {
        fprintf(stderr, "usage: platform_driver time LOG REPEATS | count LOG\n");
        return 2;
    }
    return 0;
}
