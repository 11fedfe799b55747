/* Hand-written yardstick of the flux observer's runtime step (Lee et al. 2010, gradient correction,
 * fixed inductance, ODrive's discretization and PLL): see ref_step_pmsm_flux_observer.c (benchmarks
 * only). */
#ifndef REF_STEP_PMSM_FLUX_OBSERVER_H
#define REF_STEP_PMSM_FLUX_OBSERVER_H

typedef struct {
    double x_a, x_b, lam, u_a, u_b, th, w, rejects; /* as the generated state */
} ref_flux_state;

typedef struct {
    double R, L, psi, T, TR, Tk2, adapt_rate, lam_lo, lam_hi, Tkp, Tki, k, b_x, b_lam, b_u, b_w;
} ref_flux_coef;

typedef struct {
    ref_flux_state x;
    ref_flux_coef c;
} ref_flux_observer;

/* p: R_s L_d L_q psi_pm k_slow u_ref scheduled adapt k_p k_i T_s w_max u_max k_0 (the generated
 * parameter struct's order; scheduled = 0: ODrive's constant gain) */
void ref_flux_init(ref_flux_observer *o, const double p[14]);
/* in: i_alpha i_beta u_alpha u_beta; out: w_hat theta_hat theta_pll eta_alpha eta_beta k_obs valid
 * reset (the generated output struct's order) */
void ref_flux_step(ref_flux_observer *o, const double in[4], double out[8]);

#endif
