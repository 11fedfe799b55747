/* Hand-written C reference of the speed-adaptive observer's runtime step (Piippo, Hinkkanen, Luomi
 * 2008: discretization zoh, law (16), HF injection), a YARDSTICK for benchmarks/bench_codegen.py only:
 * it is what a careful engineer would type from docs/families/ipmsm_adaptive.md, with every
 * parameter-only quantity precomputed, including the runtime contract's guard (the state's bounds),
 * coasting and self-reset (symbolic/runtime.py: the counter of rejected samples goes up by one per
 * rejected and down by one per accepted sample, not below 0; at RESET_AFTER, or if coasting would leave
 * the bounds, the state is reset), written with branches: the coasting state is computed and checked
 * only when a sample is rejected. The product is the generated code; this file exists to measure it
 * against (the benchmark also checks that both compute the same). */
#include <math.h>

#include "ref_step_ipmsm_adaptive.h"

#define PI 3.141592653589793
#define X_MAX 1e30      /* symbolic/runtime.py */
#define RESET_AFTER 100 /* symbolic/runtime.py */

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
    const double T = p[5], w_c = p[7], B = p[12], w_l = p[13];
    const double Kb = w_c / tan(w_c * T / 2), Kl = w_l / tan(w_l * T / 2);
    const double ab = Kb * Kb + B * Kb + w_c * w_c;
    const double al = Kl * Kl + sqrt(2.0) * w_l * Kl + w_l * w_l;
    const double D = w_c * T;
    const double K_eps = p[8] / w_c * (p[2] - p[1]) / (4 * p[2] * p[1]);
    const double K = p[6] > 0 ? K_eps : 1.0;
    ref_coef *c = &o->c;
    c->T = T;
    c->T2 = T / 2;
    c->R_s = p[0];
    c->inv_Ld = 1 / p[1];
    c->inv_Lq = 1 / p[2];
    c->R_Ld = p[0] / p[1];
    c->R_Lq = p[0] / p[2];
    c->psi_pm = p[3];
    c->kpLq = 2 * p[4] / p[3] * p[2]; /* k_p of (10) times C1 of (8) */
    c->kiLq = p[4] * p[4] / p[3] * p[2];
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
    c->psi_b = 4 * p[3]; /* the state's bounds (step.py) */
    c->w_b = fmin(2 * p[15], PI / (2 * T));
    reset_state(o);
}

void ref_step(ref_observer *o, const double in[4], double out[12])
{
    const ref_coef *c = &o->c;
    const ref_state x = o->x;
    ref_state n;
    const double T = c->T, T2 = c->T2;
    /* gain (16) at the stored estimate */
    const double ratio = x.w_hat * c->inv_wl;
    const double l1 = c->lambda_p * fmin(fabs(ratio), 1.0);
    const double l2 = c->lambda_p * fmax(fmin(ratio, 1.0), -1.0);
    /* measurements into the estimated frame */
    const double co = cos(x.theta), si = sin(x.theta);
    const double i_d = co * in[0] + si * in[1], i_q = co * in[1] - si * in[0];
    const double u_d = co * in[2] + si * in[3], u_q = co * in[3] - si * in[2];
    /* current estimate (5), error (6), error term (8) and speed (9) at t_k */
    const double ih_d = (x.psi_d - c->psi_pm) * c->inv_Ld, ih_q = x.psi_q * c->inv_Lq;
    const double e_d = i_d - ih_d, e_q = i_q - ih_q;
    const double w0 = x.w_i - c->kpLq * e_q;
    const double dw_i = -c->kiLq * e_q;
    /* fade, HF chain (17)-(18), PI (21)-(22) */
    const double fd = c->inj * fmax(0.0, 1.0 - fabs(w0) * c->inv_wD);
    const double y_bp = c->bp_b0 * i_q + x.bp1;
    const double m = c->g_dem * y_bp * sin(x.phi_c - c->delay);
    const double e = c->lp_b0 * m + x.lp1;
    const double eps = fd > 0 ? e : 0.0;
    const double w_eps = c->gamma_p * eps + x.x_eps;
    /* zoh: the current error held over the period, so w_i and theta_hat advance exactly */
    const double w = w0 + T2 * dw_i;
    const double cb = cos(T * w), sb = sin(T * w); /* back to the frame of t_k+1 */
    /* (20) without voltage and rotation, g = -R_s i_hat + lambda i_tilde + w_eps J psi, at t_k */
    const double le_d = l1 * e_d - l2 * e_q, le_q = l2 * e_d + l1 * e_q;
    const double h_d = T2 * (le_d - c->R_s * ih_d - w_eps * x.psi_q);
    const double h_q = T2 * (le_q - c->R_s * ih_q + w_eps * x.psi_d);
    /* flux + exact ZOH voltage + half of g0, rotated into the frame of t_k+1 */
    const double v_d = x.psi_d + T * u_d + h_d, v_q = x.psi_q + T * u_q + h_q;
    const double r_d = cb * v_d + sb * v_q, r_q = cb * v_q - sb * v_d;
    /* predictor (Euler for g), then g at the predicted flux, the current error held */
    const double p_d = r_d + cb * h_d + sb * h_q, p_q = r_q + cb * h_q - sb * h_d;
    double sum;
    n.psi_d = r_d + T2 * (le_d - c->R_Ld * (p_d - c->psi_pm) - w_eps * p_q);
    n.psi_q = r_q + T2 * (le_q - c->R_Lq * p_q + w_eps * p_d);
    n.w_i = x.w_i + T * dw_i;
    n.theta = wrap(x.theta + T * w);
    n.w_hat = w;
    n.phi_c = wrap(x.phi_c + c->dphi);
    n.bp1 = -c->bp_a1 * y_bp + x.bp2;
    n.bp2 = -c->bp_b0 * i_q - c->bp_a2 * y_bp;
    n.lp1 = 2 * c->lp_b0 * m - c->lp_a1 * e + x.lp2;
    n.lp2 = c->lp_b0 * m - c->lp_a2 * e;
    n.x_eps = fmin(fmax(x.x_eps + T * (fd * c->gamma_i * eps), -c->x_max), c->x_max);
    n.rejects = x.rejects > 0 ? x.rejects - 1 : x.rejects;
    /* the guard: the bounded fields within their bounds, the filter states finite */
    sum = fabs(n.bp1) + fabs(n.bp2) + fabs(n.lp1) + fabs(n.lp2);
    out[11] = 0;
    if (fabs(n.psi_d) <= c->psi_b && fabs(n.psi_q) <= c->psi_b && fabs(n.w_i) <= c->w_b &&
        fabs(n.theta) <= PI && fabs(w) <= c->w_b && fabs(n.phi_c) <= PI && fabs(n.x_eps) <= c->x_max &&
        sum <= X_MAX) {
        o->x = n;
        out[0] = w;
        out[4] = fd * c->u_c * cos(x.phi_c);
        out[5] = eps;
        out[6] = w_eps;
        out[9] = fd;
        out[10] = 1;
    } else { /* coast: the angles advance, the rest is held; no carrier */
        const double theta = wrap(x.theta + T * x.w_hat);
        out[0] = x.w_hat;
        out[4] = out[5] = out[9] = out[10] = 0;
        out[6] = x.x_eps;
        if (x.rejects + 1 >= RESET_AFTER || !(fabs(theta) <= PI && fabs(n.phi_c) <= PI)) {
            reset_state(o); /* too many rejected samples, or coasting would leave the bounds */
            out[11] = 1;
        } else {
            o->x.theta = theta;
            o->x.phi_c = n.phi_c;
            o->x.rejects = x.rejects + 1;
        }
    }
    out[1] = x.theta;
    out[2] = x.psi_d;
    out[3] = x.psi_q;
    out[7] = l1;
    out[8] = l2;
}
