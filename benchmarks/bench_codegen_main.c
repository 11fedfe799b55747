/* Driver of benchmarks/bench_codegen.py: times the generated step (piippo2008_step) against the
 * hand-written yardstick (ref_step) on a recorded trajectory, in one process.
 *   bench MODE samples.bin [passes]
 * MODE: check (max relative output difference), time (median ns/step of each, interleaved),
 *       gen / ref (one pass of one implementation: for callgrind instruction counts). */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "piippo2008.h"
#include "ref_step_000.h"

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static void ref_params(double p[17])
{
    const piippo2008_params *d = &piippo2008_default_params;
    const double v[17] = {d->R_s, d->L_d, d->L_q, d->psi_pm, d->alpha_fo, d->T_s, d->injection,
                          d->w_c, d->u_c, d->alpha_i, d->w_Delta, d->x_eps_max, d->w_bp, d->w_lp,
                          d->carrier_delay, d->lambda_p, d->w_lambda};
    memcpy(p, v, sizeof v);
}

static double sink; /* keeps the outputs alive */

static void run_gen(const double *m, long n)
{
    static piippo2008_observer o;
    piippo2008_output out;
    piippo2008_input in;
    long k;
    piippo2008_init(&o, &piippo2008_default_params);
    for (k = 0; k < n; ++k) {
        in.i_alpha = m[4 * k];
        in.i_beta = m[4 * k + 1];
        in.u_alpha = m[4 * k + 2];
        in.u_beta = m[4 * k + 3];
        piippo2008_step(&o, &in, &out);
        sink += out.w_hat;
    }
}

static void run_ref(const double *m, long n)
{
    static ref_observer o;
    double p[17], out[11];
    long k;
    ref_params(p);
    ref_init(&o, p);
    for (k = 0; k < n; ++k) {
        ref_step(&o, m + 4 * k, out);
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
        static piippo2008_observer g;
        static ref_observer r;
        double p[17], yr[11], worst = 0, scale[11] = {0}, diff[11] = {0};
        piippo2008_input in;
        piippo2008_output y;
        long k;
        int j;
        ref_params(p);
        ref_init(&r, p);
        piippo2008_init(&g, &piippo2008_default_params);
        for (k = 0; k < n; ++k) {
            in.i_alpha = m[4 * k];
            in.i_beta = m[4 * k + 1];
            in.u_alpha = m[4 * k + 2];
            in.u_beta = m[4 * k + 3];
            piippo2008_step(&g, &in, &y);
            ref_step(&r, m + 4 * k, yr);
            for (j = 0; j < 11; ++j) {
                double d = fabs(((double *)&y)[j] - yr[j]);
                if (j == 1) d = fabs(remainder(d, 2 * 3.141592653589793));
                if (d > diff[j]) diff[j] = d;
                if (fabs(yr[j]) > scale[j]) scale[j] = fabs(yr[j]);
            }
        }
        for (j = 0; j < 11; ++j)
            if (scale[j] > 0 && diff[j] / scale[j] > worst) worst = diff[j] / scale[j];
        printf("%.3e\n", worst);
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
