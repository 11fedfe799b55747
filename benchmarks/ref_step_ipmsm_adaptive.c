/* Hand-written C reference of the speed-adaptive observer's runtime step (Piippo, Hinkkanen, Luomi
 * 2008: Heun, law (16), HF injection), a YARDSTICK for benchmarks/bench_codegen.py only: it is what a
 * careful engineer would type from docs/families/ipmsm_adaptive.md, with every parameter-only
 * quantity precomputed, including the runtime contract's guard (the state's bounds), coasting and
 * self-reset after RESET_AFTER rejected samples in a row (symbolic/runtime.py), written with
 * branches: the coasting state is computed and checked only when a sample is rejected. The product
 * is the generated code; this file exists to measure it against (the benchmark also checks that
 * both compute the same). */
#include <math.h>

#include "ref_step_ipmsm_adaptive.h"

#define PI 3.141592653589793
#define X_MAX 1e30       /* symbolic/runtime.py */
#define RESET_AFTER 100  /* symbolic/runtime.py */

static double wrap(double th) /* to (-pi, pi], symbolic/frames.py */
{
    const double r = th - 2.0 * PI * ceil((th - PI) * (1.0 / (2.0 * PI)));
    return r > PI ? r - 2.0 * PI : r;
}

static void reset_state(ref_observer *o)
{
    o->x.psi_d = o->c.psi_pm;
    o->x.psi_q = o->x.w_i = o->x.theta = o->x.w_hat = o->x.phi_c = 0;
    o->x.bp1 = o->x.bp2 = o->x.lp1 = o->x.lp2 = o->x.x_eps = o->x.rejects = 0;
}

void ref_init(ref_observer *o, const double p[18])
{
    /* p: R_s L_d L_q psi_pm alpha_fo T_s injection w_c u_c alpha_i w_Delta x_eps_max w_bp w_lp
     *    carrier_delay w_max lambda_p w_lambda */
    const double T = p[5], w_c = p[7], B = p[12], w_l = p[13];
    const double Kb = w_c / tan(w_c * T / 2), Kl = w_l / tan(w_l * T / 2);
    const double ab = Kb * Kb + B * Kb + w_c * w_c;
    const double al = Kl * Kl + sqrt(2.0) * w_l * Kl + w_l * w_l;
    const double D = w_c * T;
    const double K_eps = p[8] / w_c * (p[2] - p[1]) / (4 * p[2] * p[1]);
    const double K = p[6] > 0 ? K_eps : 1.0;
    ref_coef *c = &o->c;
    c->T = T;
    c->R_s = p[0];
    c->inv_Ld = 1 / p[1];
    c->inv_Lq = 1 / p[2];
    c->L_q = p[2];
    c->psi_pm = p[3];
    c->k_p = 2 * p[4] / p[3];
    c->k_i = p[4] * p[4] / p[3];
    c->inj = p[6];
    c->u_c = p[8];
    c->inv_wD = 1 / p[10];
    c->x_max = p[11];
    c->dphi = D;
    c->delay = (p[14] + 0.5) * D;
    c->g_dem = 2 * sin(D / 2) / D;
    c->bp_b0 = B * Kb / ab;
    c->bp_a1 = 2 * (w_c * w_c - Kb * Kb) / ab;
    c->bp_a2 = (Kb * Kb - B * Kb + w_c * w_c) / ab;
    c->lp_b0 = w_l * w_l / al;
    c->lp_a1 = 2 * (w_l * w_l - Kl * Kl) / al;
    c->lp_a2 = (Kl * Kl - sqrt(2.0) * w_l * Kl + w_l * w_l) / al;
    c->gamma_p = p[9] / (2 * K);
    c->gamma_i = p[9] * p[9] / (6 * K);
    c->lambda_p = p[16];
    c->inv_wl = 1 / p[17];
    c->psi_b = 4 * p[3];                       /* the state's bounds (step.py) */
    c->w_b = fmin(2 * p[15], PI / (2 * T));
    reset_state(o);
}

typedef struct {
    double dpsi_d, dpsi_q, dw_i, w;
} rates;

/* eqs. (5), (6), (8), (9), (20) in the estimated frame; i held, u given */
static rates f(const ref_coef *c, double psi_d, double psi_q, double w_i, double i_d, double i_q,
               double u_d, double u_q, double l1, double l2, double w_eps)
{
    rates r;
    const double ih_d = (psi_d - c->psi_pm) * c->inv_Ld, ih_q = psi_q * c->inv_Lq;
    const double e_d = i_d - ih_d, e_q = i_q - ih_q;
    const double F = c->L_q * e_q;
    const double w = -c->k_p * F + w_i;
    const double wr = w - w_eps;
    r.w = w;
    r.dw_i = -c->k_i * F;
    r.dpsi_d = u_d - c->R_s * ih_d + wr * psi_q + (l1 * e_d - l2 * e_q);
    r.dpsi_q = u_q - c->R_s * ih_q - wr * psi_d + (l2 * e_d + l1 * e_q);
    return r;
}

void ref_step(ref_observer *o, const double in[4], double out[12])
{
    const ref_coef *c = &o->c;
    const ref_state x = o->x;
    ref_state n;
    const double T = c->T;
    /* gain (16) at the stored estimate */
    const double ratio = x.w_hat * c->inv_wl;
    const double l1 = c->lambda_p * fmin(fabs(ratio), 1.0);
    const double l2 = c->lambda_p * fmax(fmin(ratio, 1.0), -1.0);
    /* measurements into the estimated frame */
    const double co = cos(x.theta), si = sin(x.theta);
    const double i_d = co * in[0] + si * in[1], i_q = co * in[1] - si * in[0];
    const double u_d = co * in[2] + si * in[3], u_q = co * in[3] - si * in[2];
    /* speed (9) at t_k, fade, HF chain (17)-(18), PI (21)-(22) */
    const double w0 = -c->k_p * c->L_q * (i_q - x.psi_q * c->inv_Lq) + x.w_i;
    const double fd = c->inj * fmax(0.0, 1.0 - fabs(w0) * c->inv_wD);
    const double y_bp = c->bp_b0 * i_q + x.bp1;
    const double m = c->g_dem * y_bp * sin(x.phi_c - c->delay);
    const double e = c->lp_b0 * m + x.lp1;
    const double eps = fd > 0 ? e : 0.0;
    const double w_eps = c->gamma_p * eps + x.x_eps;
    double x_eps = x.x_eps + T * (fd * c->gamma_i * eps);
    rates r0, r1;
    double w, th1, co1, si1, sum;
    int ok;
    x_eps = fmin(fmax(x_eps, -c->x_max), c->x_max);
    /* Heun */
    r0 = f(c, x.psi_d, x.psi_q, x.w_i, i_d, i_q, u_d, u_q, l1, l2, w_eps);
    th1 = x.theta + T * r0.w;
    co1 = cos(th1);
    si1 = sin(th1);
    r1 = f(c, x.psi_d + T * r0.dpsi_d, x.psi_q + T * r0.dpsi_q, x.w_i + T * r0.dw_i, i_d, i_q,
           co1 * in[2] + si1 * in[3], co1 * in[3] - si1 * in[2], l1, l2, w_eps);
    w = (r0.w + r1.w) / 2;
    n.psi_d = x.psi_d + T / 2 * (r0.dpsi_d + r1.dpsi_d);
    n.psi_q = x.psi_q + T / 2 * (r0.dpsi_q + r1.dpsi_q);
    n.w_i = x.w_i + T / 2 * (r0.dw_i + r1.dw_i);
    n.theta = wrap(x.theta + T * w);
    n.w_hat = w;
    n.phi_c = wrap(x.phi_c + c->dphi);
    n.bp1 = -c->bp_a1 * y_bp + x.bp2;
    n.bp2 = -c->bp_b0 * i_q - c->bp_a2 * y_bp;
    n.lp1 = 2 * c->lp_b0 * m - c->lp_a1 * e + x.lp2;
    n.lp2 = c->lp_b0 * m - c->lp_a2 * e;
    n.x_eps = x_eps;
    n.rejects = 0;
    /* the guard: the bounded fields within their bounds, the filter states finite */
    sum = fabs(n.bp1) + fabs(n.bp2) + fabs(n.lp1) + fabs(n.lp2);
    ok = fabs(n.psi_d) <= c->psi_b && fabs(n.psi_q) <= c->psi_b && fabs(n.w_i) <= c->w_b &&
         fabs(n.theta) <= PI && fabs(n.w_hat) <= c->w_b && fabs(n.phi_c) <= PI && fabs(n.x_eps) <= c->x_max &&
         sum <= X_MAX;
    out[11] = 0;
    if (ok) {
        o->x = n;
        out[0] = w;
        out[4] = fd * c->u_c * cos(x.phi_c);
        out[5] = eps;
        out[6] = w_eps;
        out[9] = fd;
        out[10] = 1;
    } else { /* coast; after RESET_AFTER rejected samples in a row, reset (the angles stay wrapped:
              * the coasting state cannot leave the bounds) */
        o->x.theta = wrap(x.theta + T * x.w_hat);
        o->x.phi_c = n.phi_c;
        out[0] = x.w_hat;
        out[4] = out[5] = out[9] = out[10] = 0;
        out[6] = x.x_eps;
        if (++o->x.rejects >= RESET_AFTER) {
            reset_state(o);
            out[11] = 1;
        }
    }
    out[1] = x.theta;
    out[2] = x.psi_d;
    out[3] = x.psi_q;
    out[7] = l1;
    out[8] = l2;
}
