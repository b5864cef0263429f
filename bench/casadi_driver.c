/*
 * casadi_driver.c -- the CasADi-generated whole-log chunk function
 * (generated/pneumatic_cylinder/casadi/, pneumatic_cylinder_chunk: L samples per call,
 * the function CasadiFdi.run calls) driven from C with preallocated work vectors: what
 * the CasADi arithmetic itself costs per sample, without CasADi's Python/C++ call layer.
 *
 *   casadi_driver LOG REPEATS WINDOW P1 .. P12
 *       WINDOW: the RMS window N of the design; P1..P12: the model parameters (model
 *       order). Prints "<wall ns/sample> <thread-cpu ns/sample>" per repeat after a "--"
 *       line (the first pass warms up; REPEATS = 0: that pass only, for callgrind), then
 *       "check <samples> <flags> <fault_class> <r_0> .. <r_nr-1>" of the last sample
 *       processed, for bench_c.casadi_native to compare with the C core.
 *
 * The chunk's signature (fdigen.backends.casadi_backend.log_functions.chunk_function):
 *   arg: small[s], u[nu x L], y[ny x L], p[np x L], oldest[nr x L]
 *   res: small_next[s], r[nr x L], rms[nr x L], flags[1 x L], fault_class[1 x L],
 *        action[1 x L], aux[na x L], faults[1 x L], sq[nr x L]
 * The moving-RMS window is outside the recursion, as in CasadiFdi.run: the squares each
 * chunk returns (sq) are kept, and the squares leaving the window at sample k (oldest)
 * are those that entered it at k - N (zero for k < N). A chunk is at most N samples
 * long, so they are all known before the chunk runs. Column-major nr x L blocks are
 * C-order (L, nr) row ranges: row N + k of the square history holds the squares entering
 * at sample k, and row k those leaving at sample k -- no copies.
 */
#define _POSIX_C_SOURCE 200809L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "pneumatic_cylinder_casadi.h"

#define NP 12
#define NOUT 9
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

static void *alloc(size_t n)
{
    void *p = calloc(n > 0 ? n : 1, 1);
    if (p == NULL) {
        fprintf(stderr, "out of memory\n");
        exit(2);
    }
    return p;
}

int main(int argc, char **argv)
{
    FILE *f;
    int64_t k64;
    casadi_int sz_arg, sz_res, sz_iw, sz_w, nstate, L, nu, ny, np_, nr, na, rows[NOUT];
    const casadi_real **arg;
    casadi_real **res, *w, *s0, *s1, *p, *out[NOUT], *sq;
    casadi_int *iw;
    long c, nchunks, N, last;
    int r, repeats, o;
    if (argc < 4 + NP) {
        fprintf(stderr, "usage: casadi_driver LOG REPEATS WINDOW P1 .. P12\n");
        return 2;
    }
    repeats = atoi(argv[2]);
    N = atol(argv[3]);
    for (o = 0; o < NP; ++o) {
        P0[o] = strtod(argv[4 + o], NULL);
    }
    if (pneumatic_cylinder_chunk_n_in() != 5 || pneumatic_cylinder_chunk_n_out() != NOUT
        || strcmp(pneumatic_cylinder_chunk_name_in(4), "oldest") != 0
        || strcmp(pneumatic_cylinder_chunk_name_out(7), "faults") != 0
        || strcmp(pneumatic_cylinder_chunk_name_out(NOUT - 1), "sq") != 0) {
        fprintf(stderr, "unexpected chunk signature (%d in, %d out)\n",
                (int)pneumatic_cylinder_chunk_n_in(), (int)pneumatic_cylinder_chunk_n_out());
        return 2;
    }
    f = fopen(argv[1], "rb");
    if (f == NULL || fread(&k64, sizeof k64, 1, f) != 1) {
        return 2;
    }
    K = (long)k64;
    U = alloc(sizeof(double) * (size_t)K);
    Y = alloc(sizeof(double) * 4 * (size_t)K);
    if (fread(U, sizeof(double), (size_t)K, f) != (size_t)K
        || fread(Y, sizeof(double), 4 * (size_t)K, f) != 4 * (size_t)K) {
        return 2;
    }
    fclose(f);

    pneumatic_cylinder_chunk_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    nstate = pneumatic_cylinder_chunk_sparsity_in(0)[0];
    nu = pneumatic_cylinder_chunk_sparsity_in(1)[0];
    L = pneumatic_cylinder_chunk_sparsity_in(1)[1];
    ny = pneumatic_cylinder_chunk_sparsity_in(2)[0];
    np_ = pneumatic_cylinder_chunk_sparsity_in(3)[0];
    nr = pneumatic_cylinder_chunk_sparsity_in(4)[0];
    for (o = 0; o < NOUT; ++o) {
        rows[o] = pneumatic_cylinder_chunk_sparsity_out(o)[0];
    }
    na = rows[6];
    if (nu != 1 || ny != 4 || np_ != NP || L > N || rows[1] != nr || rows[NOUT - 1] != nr) {
        fprintf(stderr, "unexpected sizes: nu %d ny %d np %d L %d N %ld nr %d\n", (int)nu,
                (int)ny, (int)np_, (int)L, N, (int)nr);
        return 2;
    }
    nchunks = K / (long)L;
    arg = alloc(sizeof(*arg) * (size_t)sz_arg);
    res = alloc(sizeof(*res) * (size_t)sz_res);
    iw = alloc(sizeof(*iw) * (size_t)sz_iw);
    w = alloc(sizeof(*w) * (size_t)sz_w);
    s0 = alloc(sizeof(double) * (size_t)nstate);
    s1 = alloc(sizeof(double) * (size_t)nstate);
    p = alloc(sizeof(double) * NP * (size_t)L);
    for (c = 0; c < L; ++c) {
        memcpy(p + NP * c, P0, sizeof P0);
    }
    for (o = 1; o < NOUT - 1; ++o) {     /* r, rms, flags, class, action, aux, faults */
        out[o] = alloc(sizeof(double) * (size_t)(rows[o] * L));
    }
    sq = alloc(sizeof(double) * (size_t)((N + nchunks * L) * nr));
    for (r = -1; r < repeats; ++r) {
        double w0, c0, w1, c1;
        memset(s0, 0, sizeof(double) * (size_t)nstate);      /* not initialised */
        memset(sq, 0, sizeof(double) * (size_t)(N * nr));     /* nothing leaves before N */
        w0 = ns(CLOCK_MONOTONIC);
        c0 = ns(CLOCK_THREAD_CPUTIME_ID);
        for (c = 0; c < nchunks; ++c) {
            double *tmp;
            arg[0] = s0;
            arg[1] = U + c * L;
            arg[2] = Y + 4 * c * L;
            arg[3] = p;
            arg[4] = sq + c * L * nr;                 /* squares leaving: samples - N */
            res[0] = s1;
            for (o = 1; o < NOUT - 1; ++o) {
                res[o] = out[o];
            }
            res[NOUT - 1] = sq + (N + c * L) * nr;    /* squares entering */
            if (pneumatic_cylinder_chunk(arg, res, iw, w, 0) != 0) {
                fprintf(stderr, "chunk failed\n");
                return 3;
            }
            sink = out[2][0];
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
    last = L - 1;        /* the last sample of the last chunk */
    printf("check %ld %.0f %.0f", nchunks * (long)L, out[3][last], out[4][last]);
    for (o = 0; o < nr; ++o) {
        printf(" %.17g", out[1][last * nr + o]);
    }
    printf("\n");
    return 0;
}
