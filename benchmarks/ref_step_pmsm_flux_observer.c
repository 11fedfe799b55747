/* Hand-written yardstick of the flux observer's runtime step, written from the equations of
 * docs/families/pmsm_flux_observer.md (gradient correction, fixed inductance, constant gain) with
 * every parameter-only quantity precomputed, and the runtime contract's guard (symbolic/runtime.py)
 * written with branches: bounds, coasting on the previous state, the counter and the self-reset. */
#include "ref_step_pmsm_flux_observer.h"

#include <math.h>

#define PI_ 3.14159265358979323846
#define RESET_AFTER 100.0

static double wrap(double t)
{
    double r = t - 2 * PI_ * ceil((t - PI_) * (1 / (2 * PI_)));
    return r > PI_ ? r - 2 * PI_ : r;
}

static void reset(ref_flux_observer *o)
{
    ref_flux_state *x = &o->x;
    x->x_a = o->c.psi;
    x->x_b = 0;
    x->lam = o->c.psi;
    x->u_a = x->u_b = x->th = x->w = x->rejects = 0;
}

void ref_flux_init(ref_flux_observer *o, const double p[14])
{
    ref_flux_coef *c = &o->c;
    const double T = p[10];
    c->R = p[0];
    c->L = (p[1] + p[2]) / 2;
    c->psi = p[3];
    c->T = T;
    c->TR = T * p[0];
    c->k = p[13];
    c->Tk2 = T * p[13] / 2 / (p[3] * p[3]);
    c->adapt_rate = p[7] * 0.2;
    c->lam_lo = 0.3 * p[3];
    c->lam_hi = 2.5 * p[3];
    c->Tkp = T * p[8];
    c->Tki = T * p[9];
    c->b_x = 6 * p[3];
    c->b_lam = 2.5 * p[3];
    c->b_u = p[12];
    c->b_w = fmin(p[11], PI_ / (2 * T));
    reset(o);
}

void ref_flux_step(ref_flux_observer *o, const double in[4], double out[8])
{
    const ref_flux_coef *c = &o->c;
    ref_flux_state *x = &o->x;
    const double ia = in[0], ib = in[1];
    /* candidate: prediction with the stored voltage, gradient correction, PLL */
    const double xpa = x->x_a + c->T * x->u_a - c->TR * ia, xpb = x->x_b + c->T * x->u_b - c->TR * ib;
    const double epa = xpa - c->L * ia, epb = xpb - c->L * ib;
    const double e2 = epa * epa + epb * epb, lam = x->lam;
    const double g = c->Tk2 * (lam * lam - e2);
    const double xa = xpa + g * epa, xb = xpb + g * epb;
    const double ea = xa - c->L * ia, eb = xb - c->L * ib;
    double lam_n = lam + c->adapt_rate * c->Tk2 * lam * (e2 - lam * lam);
    lam_n = fmin(fmax(lam_n, c->lam_lo), c->lam_hi);
    const double th_obs = atan2(eb, ea);
    const double th_pred = x->th + c->T * x->w;
    const double err = wrap(th_obs - th_pred);
    const double th_n = wrap(th_pred + c->Tkp * err);
    const double w_n = fmin(fmax(x->w + c->Tki * err, -c->b_w), c->b_w); /* clamped, not rejected */
    const int valid = fabs(xa) <= c->b_x && fabs(xb) <= c->b_x && fabs(lam_n) <= c->b_lam &&
                      fabs(in[2]) <= c->b_u && fabs(in[3]) <= c->b_u && fabs(th_n) <= PI_ &&
                      fabs(w_n) <= c->b_w;
    if (valid) {
        x->x_a = xa;
        x->x_b = xb;
        x->lam = lam_n;
        x->u_a = in[2];
        x->u_b = in[3];
        x->th = th_n;
        x->w = w_n;
        if (x->rejects > 0) x->rejects -= 1;
        out[0] = w_n;
        out[1] = th_obs;
        out[2] = th_n;
        out[3] = ea;
        out[4] = eb;
        out[5] = c->k;
        out[6] = 1;
        out[7] = 0;
        return;
    }
    {
        /* coast: the flux state turns at the PLL speed, the PLL runs on; nothing of the sample used */
        const double a = x->w * c->T, ca = cos(a), sa = sin(a);
        const double xca = ca * x->x_a - sa * x->x_b, xcb = sa * x->x_a + ca * x->x_b;
        const double thc = wrap(x->th + c->T * x->w);
        const int coast_ok = fabs(xca) <= c->b_x && fabs(xcb) <= c->b_x && fabs(thc) <= PI_;
        out[0] = x->w;
        out[1] = thc;
        out[2] = thc;
        out[3] = xca;
        out[4] = xcb;
        out[5] = c->k;
        out[6] = 0;
        if (x->rejects + 1 >= RESET_AFTER || !coast_ok) {
            reset(o);
            out[7] = 1;
            return;
        }
        x->x_a = xca;
        x->x_b = xcb;
        x->th = thc;
        x->rejects += 1;
        out[7] = 0;
    }
}
