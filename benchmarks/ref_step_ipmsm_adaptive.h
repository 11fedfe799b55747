/* Hand-written yardstick of the speed-adaptive observer's runtime step (Piippo et al. 2008):
 * see ref_step_ipmsm_adaptive.c (benchmarks only). */
#ifndef REF_STEP_IPMSM_ADAPTIVE_H
#define REF_STEP_IPMSM_ADAPTIVE_H

typedef struct {
    double psi_d, psi_q, w_i, theta, w_hat, phi_c, bp1, bp2, lp1, lp2, x_eps, rejects;
} ref_state;

typedef struct {
    double T, R_s, inv_Ld, inv_Lq, L_q, psi_pm, k_p, k_i, inj, u_c, inv_wD, x_max, dphi, delay, g_dem;
    double bp_b0, bp_a1, bp_a2, lp_b0, lp_a1, lp_a2, gamma_p, gamma_i, lambda_p, inv_wl, psi_b, w_b;
} ref_coef;

typedef struct {
    ref_state x;
    ref_coef c;
} ref_observer;

void ref_init(ref_observer *o, const double p[18]);
void ref_step(ref_observer *o, const double in[4], double out[12]);

#endif
