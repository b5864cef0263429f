/*
 * casadi_driver.c -- the CasADi-generated whole-log chunk function
 * (generated/pneumatic_cylinder/casadi/, pneumatic_cylinder_chunk: 1024 samples per call,
 * the function CasadiFdi.run calls) driven from C with preallocated work vectors: what
 * the CasADi arithmetic itself costs per sample, without CasADi's Python/C++ call layer.
 *
 *   casadi_driver LOG REPEATS P1 .. P12
 *       P1..P12: the model parameters (model order); prints "<wall ns/sample>
 *       <thread-cpu ns/sample>" per repeat after a "--" line (the first pass warms up;
 *       REPEATS = 0: that pass only, for callgrind)
 */
#define _POSIX_C_SOURCE 200809L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "pneumatic_cylinder_casadi.h"

#define NP 12
static long K;
static double *U, *Y;
static volatile double sink;
static double P0[NP];

static double ns(clockid_t id)
{
    struct timespec t;
    clock_gettime(id, &t);
    return (double)t.tv_sec * 1e9 + (double)t.tv_nsec;
}

int main(int argc, char **argv)
{
    FILE *f;
    int64_t k64;
    casadi_int sz_arg, sz_res, sz_iw, sz_w, nstate, L;
    const casadi_real **arg;
    casadi_real **res, *w, *s0, *s1, *p, *out[6];
    casadi_int *iw;
    long c, nchunks;
    int r, repeats, o;
    if (argc < 3 + NP) {
        fprintf(stderr, "usage: casadi_driver LOG REPEATS P1 .. P12\n");
        return 2;
    }
    for (o = 0; o < NP; ++o) {
        P0[o] = strtod(argv[3 + o], NULL);
    }
    f = fopen(argv[1], "rb");
    if (f == NULL || fread(&k64, sizeof k64, 1, f) != 1) {
        return 2;
    }
    K = (long)k64;
    U = malloc(sizeof(double) * (size_t)K);
    Y = malloc(sizeof(double) * 4 * (size_t)K);
    if (fread(U, sizeof(double), (size_t)K, f) != (size_t)K
        || fread(Y, sizeof(double), 4 * (size_t)K, f) != 4 * (size_t)K) {
        return 2;
    }
    fclose(f);
    repeats = atoi(argv[2]);

    pneumatic_cylinder_chunk_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    nstate = pneumatic_cylinder_chunk_sparsity_in(0)[0];
    L = pneumatic_cylinder_chunk_sparsity_in(1)[1];
    arg = malloc(sizeof(*arg) * (size_t)sz_arg);
    res = malloc(sizeof(*res) * (size_t)sz_res);
    iw = malloc(sizeof(*iw) * (size_t)(sz_iw > 0 ? sz_iw : 1));
    w = malloc(sizeof(*w) * (size_t)sz_w);
    s0 = malloc(sizeof(double) * (size_t)nstate);
    s1 = malloc(sizeof(double) * (size_t)nstate);
    p = malloc(sizeof(double) * NP * (size_t)L);
    for (c = 0; c < L; ++c) {
        memcpy(p + NP * c, P0, sizeof P0);
    }
    for (o = 0; o < 6; ++o) {
        out[o] = malloc(sizeof(double) * 10 * (size_t)L);
    }
    nchunks = K / (long)L;
    for (r = -1; r < repeats; ++r) {
        double w0, c0, w1, c1;
        memset(s0, 0, sizeof(double) * (size_t)nstate);
        w0 = ns(CLOCK_MONOTONIC);
        c0 = ns(CLOCK_THREAD_CPUTIME_ID);
        for (c = 0; c < nchunks; ++c) {
            double *tmp;
            arg[0] = s0;
            arg[1] = U + c * L;
            arg[2] = Y + 4 * c * L;
            arg[3] = p;
            res[0] = s1;
            for (o = 0; o < 6; ++o) {
                res[1 + o] = out[o];
            }
            if (pneumatic_cylinder_chunk(arg, res, iw, w, 0) != 0) {
                fprintf(stderr, "chunk failed\n");
                return 3;
            }
            sink = out[1][0];
            tmp = s0; s0 = s1; s1 = tmp;
        }
        c1 = ns(CLOCK_THREAD_CPUTIME_ID);
        w1 = ns(CLOCK_MONOTONIC);
        if (r < 0) {
            printf("--\n");
        } else {
            printf("%.4f %.4f\n", (w1 - w0) / (double)(nchunks * L),
                   (c1 - c0) / (double)(nchunks * L));
        }
    }
    return 0;
}
