/* Hand-written yardstick of the reduced-order EMF and load-torque observer's runtime step (De Angelo
 * et al. 2006): see ref_step_pmac_reduced_order.c (benchmarks only). */
#ifndef REF_STEP_PMAC_REDUCED_ORDER_H
#define REF_STEP_PMAC_REDUCED_ORDER_H

typedef struct {
    double zeta_a, zeta_b, tau, theta, w_hat, i_a, i_b, u_a, u_b, rejects; /* as the generated state */
} ref_pmac_state;

typedef struct {
    double R, g, gL, inv_J, p_r, inv_pr, kG, G_J, T, T_2, P1, P5, P5x5, w_max, tau_max;
} ref_pmac_coef;

typedef struct {
    ref_pmac_state x;
    ref_pmac_coef c;
} ref_pmac_observer;

/* p: R L J p_r g Gamma T_s T_max Phi_1 Phi_5 (the generated parameter struct's order) */
void ref_pmac_init(ref_pmac_observer *o, const double p[10]);
/* in: i_alpha i_beta u_alpha u_beta; out: w_hat theta_hat T_L_hat e_alpha e_beta phi_alpha phi_beta
 * valid reset (the generated output struct's order) */
void ref_pmac_step(ref_pmac_observer *o, const double in[4], double out[9]);

#endif
