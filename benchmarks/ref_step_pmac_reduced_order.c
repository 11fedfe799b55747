/* Hand-written C reference of the reduced-order EMF and load-torque observer's runtime step (De Angelo,
 * Bossio, Solsona, Garcia, Valla 2006, eqs. (13)-(24); the default scheme rk2-model of
 * symbolic/pmac_reduced_order/step.py for EMF harmonics of orders 1 and 5, with the runtime contract's
 * guard (the state's bounds), coasting and self-reset (symbolic/runtime.py: the counter of rejected
 * samples goes up by one per rejected and down by one per accepted sample, not below 0; at RESET_AFTER,
 * or if coasting would leave the bounds, the state is reset), a YARDSTICK for benchmarks/bench_codegen.py
 * only: what a careful engineer would type from the equations, with every parameter-only quantity
 * precomputed at init, each sine and cosine computed once per angle, the helpers inlined, and the
 * coasting computed only when a sample is rejected. No trigonometric identity the equations do not spell out (sin 5x from sin x and cos x,
 * sin(atan2(y, x)) = y / |(x, y)|, theta_hat from the branch-free angle): those would change the
 * equations in either implementation. The product is the generated code; this file exists to measure
 * it against (the benchmark also checks that both compute the same). */
#include <math.h>

#include "ref_step_pmac_reduced_order.h"

#define PI 3.141592653589793
#define X_MAX 1e30      /* symbolic/runtime.py */
#define RESET_AFTER 100 /* symbolic/runtime.py */

static double wrap(double th) /* to (-pi, pi], symbolic/frames.py */
{
    const double r = th - 2.0 * PI * ceil((th - PI) * (1.0 / (2.0 * PI)));
    return r > PI ? r - 2.0 * PI : r;
}

static void reset_state(ref_pmac_observer *o)
{
    o->x.zeta_a = o->x.zeta_b = o->x.tau = o->x.theta = o->x.w_hat = 0;
    o->x.i_a = o->x.i_b = o->x.u_a = o->x.u_b = o->x.rejects = 0;
}

void ref_pmac_init(ref_pmac_observer *o, const double p[10])
{
    /* p: R L J p_r g Gamma T_s T_max Phi_1 Phi_5 */
    ref_pmac_coef *c = &o->c;
    c->R = p[0];
    c->g = p[4];
    c->gL = p[4] * p[1];
    c->inv_J = 1 / p[2];
    c->p_r = p[3];
    c->inv_pr = 1 / p[3];
    c->kG = p[5] * p[1] / p[2]; /* Gamma L / J, eqs. (15)-(17) */
    c->G_J = p[5] / p[2];       /* Gamma L / J times di_hat = (u - R i - e_hat) / L, eq. (11) */
    c->T = p[6];
    c->T_2 = p[6] / 2;
    c->P1 = p[8];
    c->P5 = p[9];
    c->P5x5 = 5 * p[9];
    c->w_max = (PI / 2) / p[6];                      /* the step's range |w_hat| T_s <= pi/2 */
    c->tau_max = 2 * (1 + p[5] * p[1] / p[2]) * p[7]; /* the load state's bound */
    reset_state(o);
}

typedef struct {
    double s1, c1, s5, c5; /* sin, cos of the angle and of 5 times it */
} harm;

static inline harm harmonics_at(double th)
{
    harm h;
    h.s1 = sin(th);
    h.c1 = cos(th);
    h.s5 = sin(5 * th);
    h.c5 = cos(5 * th);
    return h;
}

typedef struct {
    double e_a, e_b;   /* EMF estimate e_hat = zeta - g L i, eq. (17) */
    double e1_a, e1_b; /* its fundamental: the predicted 5th harmonic removed, eqs. (19)-(22) */
} emf;

/* h5: the 5th harmonic of (19) predicted at theta~ = theta_hat + w_hat dt with the speed w_hat */
static inline emf emf_of(const ref_pmac_coef *c, double z_a, double z_b, double i_a, double i_b,
                         double h5_a, double h5_b)
{
    emf m;
    m.e_a = z_a - c->gL * i_a;
    m.e_b = z_b - c->gL * i_b;
    m.e1_a = m.e_a - h5_a;
    m.e1_b = m.e_b - h5_b;
    return m;
}

typedef struct {
    double th, w, TL;    /* theta_hat (18), w_hat (13)-(14), T_L_hat (17) */
    double phi_a, phi_b; /* phi_hat, eq. (23) */
    harm h;              /* at theta_hat */
} est;

/* the estimates on the speed-sign branch sigma, eqs. (13)-(14), (17)-(18), (23) */
static inline est estimate(const ref_pmac_coef *c, const emf *m, double tau, double i_a, double i_b,
                           double sigma)
{
    est e;
    e.th = atan2(-sigma * m->e1_a, sigma * m->e1_b);
    e.th = e.th > -PI ? e.th : PI; /* (-pi, pi], symbolic/frames.py half_open */
    e.h = harmonics_at(e.th);
    e.phi_a = -(c->P1 * e.h.s1 + c->P5 * e.h.s5);
    e.phi_b = c->P1 * e.h.c1 + c->P5 * e.h.c5;
    e.w = sigma * c->p_r *
          sqrt((m->e_a * m->e_a + m->e_b * m->e_b) / (e.phi_a * e.phi_a + e.phi_b * e.phi_b));
    e.TL = tau + c->kG * (e.phi_a * i_a + e.phi_b * i_b);
    return e;
}

/* d zeta/dt, d tau/dt of eq. (16), with d phi_hat/dt of (24) and L d i_hat/dt of (11) */
static inline void rates(const ref_pmac_coef *c, const emf *m, const est *e, double i_a, double i_b,
                         double u_a, double u_b, double *dz_a, double *dz_b, double *dtau)
{
    const double dphi_a = -e->w * (c->P1 * e->h.c1 + c->P5x5 * e->h.c5);
    const double dphi_b = -e->w * (c->P1 * e->h.s1 + c->P5x5 * e->h.s5);
    const double v_a = u_a - c->R * i_a - m->e_a, v_b = u_b - c->R * i_b - m->e_b;
    const double acc = c->inv_J * (e->phi_a * i_a + e->phi_b * i_b - e->TL);
    const double wr = e->w * c->inv_pr;
    *dz_a = dphi_a * wr + e->phi_a * acc + c->g * v_a;
    *dz_b = dphi_b * wr + e->phi_b * acc + c->g * v_b;
    *dtau = -(c->G_J * (e->phi_a * v_a + e->phi_b * v_b) + c->kG * (dphi_a * i_a + dphi_b * i_b));
}

void ref_pmac_step(ref_pmac_observer *o, const double in[4], double out[9])
{
    const ref_pmac_coef *c = &o->c;
    const ref_pmac_state x = o->x;
    ref_pmac_state n;
    const double T = c->T, w0 = x.w_hat, wr = w0 * c->inv_pr, ww = w0 * wr;
    const double sigma0 = w0 >= 0 ? 1.0 : -1.0; /* speed sign (14) over the step: the previous one */
    const double cT = cos(w0 * T), sT = sin(w0 * T); /* rotation by w0 T */
    const double th1 = x.theta + w0 * T;             /* predicted angle at t_k, eq. (21) */
    const harm h0 = harmonics_at(x.theta), h1 = harmonics_at(th1);
    /* the observer model's own EMF E = phi(theta) w0 / p_r (3)-(4) and its rate, at t_(k-1) and t_k */
    const double E0_a = -(c->P1 * h0.s1 + c->P5 * h0.s5) * wr, E0_b = (c->P1 * h0.c1 + c->P5 * h0.c5) * wr;
    const double E1_a = -(c->P1 * h1.s1 + c->P5 * h1.s5) * wr, E1_b = (c->P1 * h1.c1 + c->P5 * h1.c5) * wr;
    const double dE0_a = -(c->P1 * h0.c1 + c->P5x5 * h0.c5) * ww;
    const double dE0_b = -(c->P1 * h0.s1 + c->P5x5 * h0.s5) * ww;
    const double dE1_a = -(c->P1 * h1.c1 + c->P5x5 * h1.c5) * ww;
    const double dE1_b = -(c->P1 * h1.s1 + c->P5x5 * h1.s5) * ww;
    /* the 5th harmonic removed in (19)-(22), predicted at t_(k-1) and t_k */
    const double p0_a = -c->P5 * h0.s5 * wr, p0_b = c->P5 * h0.c5 * wr;
    const double p1_a = -c->P5 * h1.s5 * wr, p1_b = c->P5 * h1.c5 * wr;
    double k1z_a, k1z_b, k1t, k2z_a, k2z_b, k2t;
    double z0_a, z0_b, s1_a, s1_b, zp_a, zp_b, d_a, d_b, s2_a, s2_b, zn_a, zn_b, raw, dth, sigma, sum;
    emf m;
    est e;

    /* Heun in the frame rotating at w0, around the model's EMF: z = R(-w0 t)(zeta - E) */
    m = emf_of(c, x.zeta_a, x.zeta_b, x.i_a, x.i_b, p0_a, p0_b); /* stage at t_(k-1), stored samples */
    e = estimate(c, &m, x.tau, x.i_a, x.i_b, sigma0);
    rates(c, &m, &e, x.i_a, x.i_b, x.u_a, x.u_b, &k1z_a, &k1z_b, &k1t);
    z0_a = x.zeta_a - E0_a;
    z0_b = x.zeta_b - E0_b;
    s1_a = k1z_a - dE0_a + w0 * z0_b; /* dz/dt = R(-w0 t)(dzeta/dt - dE/dt) - w0 J z */
    s1_b = k1z_b - dE0_b - w0 * z0_a;
    zp_a = z0_a + T * s1_a;
    zp_b = z0_b + T * s1_b;
    m = emf_of(c, E1_a + cT * zp_a - sT * zp_b, E1_b + sT * zp_a + cT * zp_b, in[0], in[1], p1_a, p1_b);
    e = estimate(c, &m, x.tau + T * k1t, in[0], in[1], sigma0); /* stage at t_k, new samples */
    rates(c, &m, &e, in[0], in[1], in[2], in[3], &k2z_a, &k2z_b, &k2t);
    d_a = k2z_a - dE1_a;
    d_b = k2z_b - dE1_b;
    s2_a = cT * d_a + sT * d_b + w0 * zp_b;
    s2_b = cT * d_b - sT * d_a - w0 * zp_a;
    zn_a = z0_a + c->T_2 * (s1_a + s2_a);
    zn_b = z0_b + c->T_2 * (s1_b + s2_b);
    n.zeta_a = E1_a + cT * zn_a - sT * zn_b;
    n.zeta_b = E1_b + sT * zn_a + cT * zn_b;
    n.tau = x.tau + c->T_2 * (k1t + k2t);

    /* the estimates at t_k: speed sign (14) from the branch-free angle, then (18) on its branch */
    m = emf_of(c, n.zeta_a, n.zeta_b, in[0], in[1], p1_a, p1_b);
    raw = atan2(-m.e1_a, m.e1_b);
    dth = raw - x.theta;
    dth -= PI * floor(dth * (1 / PI) + 0.5); /* modulo pi, to [-pi/2, pi/2) */
    sigma = dth >= 0 ? 1.0 : -1.0;
    e = estimate(c, &m, n.tau, in[0], in[1], sigma);
    n.theta = e.th;
    n.rejects = x.rejects > 0 ? x.rejects - 1 : x.rejects; /* down per accepted sample, not below 0 */
    n.w_hat = e.w;
    n.i_a = in[0];
    n.i_b = in[1];
    n.u_a = in[2];
    n.u_b = in[3];

    /* the guard: the angle, the speed and the load state within their bounds, the rest finite */
    sum = fabs(n.zeta_a) + fabs(n.zeta_b) + fabs(n.i_a) + fabs(n.i_b) + fabs(n.u_a) + fabs(n.u_b);
    out[8] = 0;
    if (fabs(n.theta) <= PI && fabs(e.w) <= c->w_max && fabs(n.tau) <= c->tau_max && sum <= X_MAX) {
        o->x = n;
        out[0] = e.w;
        out[1] = e.th;
        out[2] = e.TL;
        out[3] = m.e_a;
        out[4] = m.e_b;
        out[5] = e.phi_a;
        out[6] = e.phi_b;
        out[7] = 1;
    } else { /* coast: the EMF turns at w0, the angle advances by w0 T; the newest finite samples kept */
        const double th_c = wrap(th1);
        const harm hc = harmonics_at(th_c);
        const double phi_a = -(c->P1 * hc.s1 + c->P5 * hc.s5), phi_b = c->P1 * hc.c1 + c->P5 * hc.c5;
        o->x.zeta_a = cT * x.zeta_a - sT * x.zeta_b;
        o->x.zeta_b = sT * x.zeta_a + cT * x.zeta_b;
        o->x.theta = th_c;
        if (fabs(in[0]) + fabs(in[1]) + fabs(in[2]) + fabs(in[3]) <= X_MAX) {
            o->x.i_a = in[0];
            o->x.i_b = in[1];
            o->x.u_a = in[2];
            o->x.u_b = in[3];
        }
        out[0] = w0;
        out[1] = th_c;
        out[2] = x.tau + c->kG * (phi_a * x.i_a + phi_b * x.i_b);
        out[3] = o->x.zeta_a - c->gL * (cT * x.i_a - sT * x.i_b);
        out[4] = o->x.zeta_b - c->gL * (sT * x.i_a + cT * x.i_b);
        out[5] = phi_a;
        out[6] = phi_b;
        out[7] = 0;
        /* at RESET_AFTER rejected samples (less the accepted ones), or coasting beyond the bounds: reset */
        sum = fabs(o->x.zeta_a) + fabs(o->x.zeta_b) + fabs(o->x.i_a) + fabs(o->x.i_b) + fabs(o->x.u_a) +
              fabs(o->x.u_b);
        if (++o->x.rejects >= RESET_AFTER || !(fabs(th_c) <= PI && sum <= X_MAX)) {
            reset_state(o);
            out[8] = 1;
        }
    }
}
