/* Hand-written yardstick of the speed-adaptive observer's runtime step (Piippo et al. 2008):
 * see ref_step_ipmsm_adaptive.c (benchmarks only). */
#ifndef REF_STEP_IPMSM_ADAPTIVE_H
#define REF_STEP_IPMSM_ADAPTIVE_H

typedef struct {
    double psi_d, psi_q, w_i, theta, w_hat, phi_c, bp1, bp2, lp1, lp2, x_eps, rejects; /* as generated */
} ref_state;

typedef struct {
    double T, T2, R_s, inv_Ld, inv_Lq, R_Ld, R_Lq, psi_pm, kpLq, kiLq, inj, u_c, inv_wD, x_max, dphi;
    double delay, g_dem, bp_b0, bp_a1, bp_a2, lp_b0, lp_a1, lp_a2, gamma_p, gamma_i, lambda_p, inv_wl;
    double psi_b, w_b;
} ref_coef;

typedef struct {
    ref_state x;
    ref_coef c;
} ref_observer;

/* p: R_s L_d L_q psi_pm alpha_fo T_s injection w_c u_c alpha_i w_Delta x_eps_max w_bp w_lp
 *    carrier_delay w_max lambda_p w_lambda (the generated parameter struct's order) */
void ref_init(ref_observer *o, const double p[18]);
/* in: i_alpha i_beta u_alpha u_beta; out: w_hat theta_hat psi_hat_d psi_hat_q u_c_d eps w_eps lambda1
 * lambda2 fade valid reset (the generated output struct's order) */
void ref_step(ref_observer *o, const double in[4], double out[12]);

#endif
