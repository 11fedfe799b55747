/* Driver of benchmarks/bench_codegen.py: times a generated step against its hand-written yardstick on a
 * recorded trajectory, in one process. Built once per observer:
 *   -DBENCH_IPMSM_ADAPTIVE      piippo2008_step      vs ref_step      (ref_step_ipmsm_adaptive.c)
 *   -DBENCH_PMAC_REDUCED_ORDER  deangelo2006_step    vs ref_pmac_step (ref_step_pmac_reduced_order.c)
 *   -DBENCH_PMSM_FLUX_OBSERVER  outrunner270_step    vs ref_flux_step (ref_step_pmsm_flux_observer.c)
 *   bench MODE samples.bin [passes]
 * MODE: check (max relative difference of the outputs and of the states; the rejected samples and the
 *       resets of the generated step), time (median ns/step of each, interleaved),
 *       gen / ref (one pass of one implementation: for callgrind instruction counts). */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#if defined(BENCH_PMAC_REDUCED_ORDER)
#include "deangelo2006.h"
#include "ref_step_pmac_reduced_order.h"
#define GEN(name) deangelo2006_##name
#define N_OUT 9
#define N_STATE 10
#define X_ANGLE2 (-1) /* the state's angles: theta (3) and this one */
#define N_PARAM 10
#define REF_INIT ref_pmac_init
#define REF_STEP ref_pmac_step
typedef ref_pmac_observer ref_obs;

static void ref_params(double p[N_PARAM])
{
    /* the generated parameter struct is R L J p_r g Gamma T_s T_max Phi_1 Phi_5, all double */
    typedef char same_layout[sizeof(deangelo2006_params) == N_PARAM * sizeof(double) ? 1 : -1];
    (void)sizeof(same_layout);
    memcpy(p, &deangelo2006_default_params, sizeof(deangelo2006_params));
}
#elif defined(BENCH_IPMSM_ADAPTIVE)
#include "piippo2008.h"
#include "ref_step_ipmsm_adaptive.h"
#define GEN(name) piippo2008_##name
#define N_OUT 12
#define N_STATE 12
#define X_ANGLE2 5 /* the state's angles: theta (3) and phi_c */
#define N_PARAM 18
#define REF_INIT ref_init
#define REF_STEP ref_step
typedef ref_observer ref_obs;

static void ref_params(double p[N_PARAM])
{
    const piippo2008_params *d = &piippo2008_default_params;
    const double v[N_PARAM] = {d->R_s, d->L_d, d->L_q, d->psi_pm, d->alpha_fo, d->T_s, d->injection,
                               d->w_c, d->u_c, d->alpha_i, d->w_Delta, d->x_eps_max, d->w_bp, d->w_lp,
                               d->carrier_delay, d->w_max, d->lambda_p, d->w_lambda};
    memcpy(p, v, sizeof v);
}
#elif defined(BENCH_PMSM_FLUX_OBSERVER)
#include "outrunner270.h"
#include "ref_step_pmsm_flux_observer.h"
#define GEN(name) outrunner270_##name
#define N_OUT 8
#define N_STATE 8
#define X_ANGLE2 5 /* the state's angles: theta_pll (5); (3) is a voltage, compared modulo 2 pi harmlessly */
#define N_PARAM 14
#define REF_INIT ref_flux_init
#define REF_STEP ref_flux_step
typedef ref_flux_observer ref_obs;

static void ref_params(double p[N_PARAM])
{
    /* the generated parameter struct: R_s L_d L_q psi_pm k_slow u_ref scheduled adapt k_p k_i T_s w_max
     * u_max k_0, all double */
    typedef char same_layout[sizeof(outrunner270_params) == N_PARAM * sizeof(double) ? 1 : -1];
    (void)sizeof(same_layout);
    memcpy(p, &outrunner270_default_params, sizeof(outrunner270_params));
}
#else
#error "define BENCH_IPMSM_ADAPTIVE, BENCH_PMAC_REDUCED_ORDER or BENCH_PMSM_FLUX_OBSERVER"
#endif

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static double sink; /* keeps the outputs alive */

/* the state structs: the same fields, all double, in the same order (angles: theta; phi_c) */
#define STATE_SIZE_OK (sizeof(GEN(state)) == sizeof(((ref_obs *)0)->x))
typedef char same_state[STATE_SIZE_OK && sizeof(GEN(state)) == N_STATE * sizeof(double) ? 1 : -1];

/* largest relative difference so far: |a - b| per component over its largest |b|; angles modulo 2 pi */
static void differ(const double *a, const double *b, int n, int angle1, int angle2, double *diff,
                   double *scale)
{
    int j;
    for (j = 0; j < n; ++j) {
        double d = fabs(a[j] - b[j]);
        if (j == angle1 || j == angle2) d = fabs(remainder(d, 2 * 3.141592653589793));
        if (!(d <= diff[j])) diff[j] = d; /* NaN sticks */
        if (fabs(b[j]) > scale[j]) scale[j] = fabs(b[j]);
    }
}

static double worst_of(const double *diff, const double *scale, int n)
{
    double worst = 0;
    int j;
    for (j = 0; j < n; ++j) {
        const double r = diff[j] == 0 ? 0 : scale[j] > 0 ? diff[j] / scale[j] : INFINITY;
        if (!(r <= worst)) worst = r;
    }
    return worst;
}

static void set_input(GEN(input) * in, const double *m)
{
    in->i_alpha = m[0];
    in->i_beta = m[1];
    in->u_alpha = m[2];
    in->u_beta = m[3];
}

static void run_gen(const double *m, long n)
{
    static GEN(observer) o;
    GEN(output) out;
    GEN(input) in;
    long k;
    GEN(init)(&o, &GEN(default_params));
    for (k = 0; k < n; ++k) {
        set_input(&in, m + 4 * k);
        GEN(step)(&o, &in, &out);
        sink += out.w_hat;
    }
}

static void run_ref(const double *m, long n)
{
    static ref_obs o;
    double p[N_PARAM], out[N_OUT];
    long k;
    ref_params(p);
    REF_INIT(&o, p);
    for (k = 0; k < n; ++k) {
        REF_STEP(&o, m + 4 * k, out);
        sink += out[0];
    }
}

static int cmp(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv)
{
    FILE *f;
    double *m;
    long n, cap = 1 << 16;
    if (argc < 3 || (f = fopen(argv[2], "rb")) == NULL) {
        fprintf(stderr, "usage: bench check|time|gen|ref samples.bin [passes]\n");
        return 2;
    }
    m = malloc(sizeof(double) * 4 * (size_t)cap);
    for (n = 0; fread(m + 4 * n, sizeof(double), 4, f) == 4;) {
        if (++n == cap) {
            cap *= 2;
            m = realloc(m, sizeof(double) * 4 * (size_t)cap);
        }
    }
    fclose(f);
    if (strcmp(argv[1], "gen") == 0) {
        run_gen(m, n);
    } else if (strcmp(argv[1], "ref") == 0) {
        run_ref(m, n);
    } else if (strcmp(argv[1], "check") == 0) {
        static GEN(observer) g;
        static ref_obs r;
        double p[N_PARAM], yr[N_OUT], worst, scale[N_OUT] = {0}, diff[N_OUT] = {0};
        double xs[N_STATE] = {0}, xd[N_STATE] = {0};
        GEN(input) in;
        GEN(output) y;
        long k, rejected = 0, resets = 0;
        ref_params(p);
        REF_INIT(&r, p);
        GEN(init)(&g, &GEN(default_params));
        for (k = 0; k < n; ++k) {
            set_input(&in, m + 4 * k);
            GEN(step)(&g, &in, &y);
            REF_STEP(&r, m + 4 * k, yr);
            differ((const double *)&y, yr, N_OUT, 1, -1, diff, scale); /* theta_hat, both observers */
            differ((const double *)&g.x, (const double *)&r.x, N_STATE, 3, X_ANGLE2, xd, xs);
            rejected += ((const double *)&y)[N_OUT - 2] == 0; /* valid, reset: the last outputs */
            resets += ((const double *)&y)[N_OUT - 1] != 0;
        }
        worst = worst_of(diff, scale, N_OUT);
        printf("%.3e %.3e %ld %ld\n", worst, worst_of(xd, xs, N_STATE), rejected, resets);
    } else {
        const int passes = argc > 3 ? atoi(argv[3]) : 21;
        double *tg = malloc(sizeof(double) * (size_t)passes), *tr = malloc(sizeof(double) * (size_t)passes);
        int i;
        run_gen(m, n); /* warm up */
        run_ref(m, n);
        for (i = 0; i < passes; ++i) {
            double t0 = now();
            run_gen(m, n);
            tg[i] = (now() - t0) / (double)n * 1e9;
            t0 = now();
            run_ref(m, n);
            tr[i] = (now() - t0) / (double)n * 1e9;
        }
        qsort(tg, (size_t)passes, sizeof(double), cmp);
        qsort(tr, (size_t)passes, sizeof(double), cmp);
        printf("%.3f %.3f\n", tg[passes / 2], tr[passes / 2]);
        free(tg);
        free(tr);
    }
    free(m);
    return sink == 12345.678 ? 1 : 0;
}
