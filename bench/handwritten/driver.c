/*
 * driver.c -- bench driver: the generated step and the hand-written step over a log.
 *
 *   driver dump gen|hand LOG OUT     outputs per sample (r, rms, aux, then the state z
 *                                    after the step, as double; flags, class, action,
 *                                    consistent faults as int32) into OUT, for the check
 *   driver dump sync LOG OUT         the hand-written step's outputs and next state when
 *                                    it starts every sample from the generated step's
 *                                    state (one-step check: no accumulated rounding)
 *   driver time LOG REPEATS          REPEATS x (generated pass, hand-written pass),
 *                                    interleaved; one line per pass:
 *                                    "<impl> <wall ns/sample> <thread-cpu ns/sample>"
 *   driver count LOG                 one pass of each (for callgrind --toggle-collect
 *                                    on loop_gen / loop_hand)
 *
 * LOG is bench/run.py's binary log: int64 K, then u[K] and y[K][4] as double.
 * Each pass starts from init (not timed) and steps over all K samples.
 */
#define _POSIX_C_SOURCE 200809L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "pneumatic_cylinder_fdi.h"
#include "fdi_hand.h"

static long K;
static double *U, *Y;
static volatile double sink;

static void read_log(const char *path)
{
    FILE *f = fopen(path, "rb");
    int64_t k;
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
}

static pneumatic_cylinder_fdi_params gp;
static pneumatic_cylinder_fdi_state gs;
static fdi_hand_params hp;
static fdi_hand_state hs;

static void init_gen(void)
{
    pneumatic_cylinder_fdi_default_params(&gp);
    if (pneumatic_cylinder_fdi_init(&gs, &gp) != 0) {
        fprintf(stderr, "init failed\n");
        exit(2);
    }
}

static void init_hand(void)
{
    double p[FDI_HAND_NP];
    pneumatic_cylinder_fdi_default_params(&gp);
    p[0] = gp.gamma; p[1] = gp.R; p[2] = gp.Ts; p[3] = gp.A; p[4] = gp.M; p[5] = gp.Ff;
    p[6] = gp.L; p[7] = gp.V0; p[8] = gp.K; p[9] = gp.Psup; p[10] = gp.Patm; p[11] = gp.P0;
    fdi_hand_init(&hs, &hp, p);
}

__attribute__((noinline)) static double loop_gen(void)
{
    pneumatic_cylinder_fdi_output out;
    double acc = 0.0;
    long k;
    for (k = 0; k < K; ++k) {
        pneumatic_cylinder_fdi_step(&gs, &gp, U + k, Y + 4 * k, &out);
        acc += out.rms[0] + (double)out.flags;
    }
    return acc;
}

__attribute__((noinline)) static double loop_hand(void)
{
    fdi_hand_output out;
    double acc = 0.0;
    long k;
    for (k = 0; k < K; ++k) {
        fdi_hand_step(&hs, &hp, U + k, Y + 4 * k, &out);
        acc += out.rms[0] + (double)out.flags;
    }
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

/* the hand-written state := the generated state (same quantities, other layout) */
static void sync_state(void)
{
    memcpy(hs.z, gs.z, sizeof hs.z);
    memcpy(hs.buf, gs.buf, sizeof hs.buf);
    memcpy(hs.sums, gs.sums, sizeof hs.sums);
    hs.index = gs.index;
    hs.flags = gs.flags;
    hs.candidate = gs.candidate;
    hs.count = gs.count;
    hs.decision = gs.decision;
    hs.initialised = gs.initialised != PNEUMATIC_CYLINDER_FDI_STATE_RESET;
    hs.frozen = gs.frozen;
    hs.late = gs.late;
    hs.action_candidate = gs.action_candidate;
    hs.action_count = gs.action_count;
    hs.action = gs.action;
}

static void dump(const char *impl, const char *path)
{
    const int sync = strcmp(impl, "sync") == 0;
    FILE *f = fopen(path, "wb");
    long k;
    if (f == NULL) {
        fprintf(stderr, "cannot write %s\n", path);
        exit(2);
    }
    if (strcmp(impl, "gen") == 0) {
        init_gen();
    } else {
        init_hand();
        if (sync) {
            init_gen();
        }
    }
    for (k = 0; k < K; ++k) {
        double d[2 * PNEUMATIC_CYLINDER_FDI_NR + 2 + PNEUMATIC_CYLINDER_FDI_NZ];
        int32_t ints[4];
        if (strcmp(impl, "gen") == 0) {
            pneumatic_cylinder_fdi_output o;
            pneumatic_cylinder_fdi_step(&gs, &gp, U + k, Y + 4 * k, &o);
            memcpy(d, o.r, sizeof o.r);
            memcpy(d + PNEUMATIC_CYLINDER_FDI_NR, o.rms, sizeof o.rms);
            memcpy(d + 2 * PNEUMATIC_CYLINDER_FDI_NR, o.aux, sizeof o.aux);
            memcpy(d + 2 * PNEUMATIC_CYLINDER_FDI_NR + 2, gs.z, sizeof gs.z);
            ints[0] = (int32_t)o.flags; ints[1] = o.fault_class; ints[2] = o.action;
            ints[3] = (int32_t)o.faults;
        } else {
            fdi_hand_output o;
            if (sync) {
                pneumatic_cylinder_fdi_output og;
                sync_state();
                pneumatic_cylinder_fdi_step(&gs, &gp, U + k, Y + 4 * k, &og);
            }
            fdi_hand_step(&hs, &hp, U + k, Y + 4 * k, &o);
            memcpy(d, o.r, sizeof o.r);
            memcpy(d + PNEUMATIC_CYLINDER_FDI_NR, o.rms, sizeof o.rms);
            memcpy(d + 2 * PNEUMATIC_CYLINDER_FDI_NR, o.aux, sizeof o.aux);
            memcpy(d + 2 * PNEUMATIC_CYLINDER_FDI_NR + 2, hs.z, sizeof hs.z);
            ints[0] = (int32_t)o.flags; ints[1] = o.fault_class; ints[2] = o.action;
            ints[3] = (int32_t)o.faults;
        }
        fwrite(d, sizeof d, 1, f);
        fwrite(ints, sizeof ints, 1, f);
    }
    fclose(f);
}

#if FDI_HAND_NR != PNEUMATIC_CYLINDER_FDI_NR
#error "hand-written and generated residual counts differ"
#endif
#if FDI_HAND_NZ != PNEUMATIC_CYLINDER_FDI_NZ
#error "hand-written and generated state sizes differ"
#endif

int main(int argc, char **argv)
{
    if (argc >= 5 && strcmp(argv[1], "dump") == 0) {
        read_log(argv[3]);
        dump(argv[2], argv[4]);
    } else if (argc >= 4 && strcmp(argv[1], "time") == 0) {
        int r, repeats = atoi(argv[3]);
        read_log(argv[2]);
        timed("gen", init_gen, loop_gen);      /* warm-up pair, not reported */
        timed("hand", init_hand, loop_hand);
        fflush(stdout);
        printf("--\n");
        for (r = 0; r < repeats; ++r) {
            if (r % 2 == 0) {
                timed("gen", init_gen, loop_gen);
                timed("hand", init_hand, loop_hand);
            } else {
                timed("hand", init_hand, loop_hand);
                timed("gen", init_gen, loop_gen);
            }
        }
    } else if (argc >= 3 && strcmp(argv[1], "count") == 0) {
        read_log(argv[2]);
        init_gen();
        sink = loop_gen();
        init_hand();
        sink = loop_hand();
    } else {
        fprintf(stderr, "usage: driver dump gen|hand LOG OUT | time LOG REPEATS | count LOG\n");
        return 2;
    }
    return 0;
}
