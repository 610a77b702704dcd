"""Closure fits of Weinhart et al. (2012) §9 and Thornton et al. §6 to a simulation campaign.

Input is a campaign table (:mod:`granflow.fitting.table`, one row per run); each fit returns a
:class:`FitResult` (params, stderr, error of Eq. 49, n_points, ok, message) that says what the
data identify (:mod:`.identify`: per-parameter status and reason, closure status ok / reduced /
unidentified / misfit / failed, held-out z-scores) and carries its parameter ensemble.  Where
the full form is not identified a stated reduced form is fitted (:mod:`.forms`); runs are
weighted by their decorrelated standard errors (:mod:`.lsq`).  Fits that cannot be made return
``ok=False`` with NaN parameters.

==========================  ===========================================================
function                    closure (equation)
==========================  ===========================================================
fit_hstop                   hstop(theta; lambda), Eq. (45), from arrested/flowing brackets
fit_hstop_eq38              exponential hstop, Eq. (38), comparison only
fit_flow_rule               F = beta h/hstop(theta; 1) - gamma, Eq. (47), error Eq. (49)
friction_closure            mu(h, F; lambda), Eq. (50)
fit_bulk_density            rho_c/rho_p = c0 - exp((theta - c2)/c1), Eq. (52)
fit_stress_ratio            K = 1 + (theta - d1)/d0, Eq. (53)
fit_alpha                   shape factor: Eq. (54) basal-layer model or constant (Eq. 55)
fit_Ps                      per-run segregation Peclet number, T-eq. (28)
fit_asymmetric_flux         asymmetric-flux steady profile (seed 001 Eq. 2.9)
fit_Ps_law                  Ps(sigma) = Pmax (1 - exp(-k (1/sigma - 1))), T-eq. (29)
combine_Ps_runs             one Ps per size ratio from several runs (replicates, starts)
fit_mu_I                    mu(I) rheology, seed 001 Eq. (2.13)
fit_campaign                all of the above from one campaign table
DisorderedWindow            delta3(H) < theta < delta_acc of one roughness (Eq. 46, 48)
==========================  ===========================================================
"""

from .campaign import DisorderedWindow, fit_campaign
from .bulk import density_eq52, fit_bulk_density, fit_stress_ratio, stress_ratio_eq53
from .flow_rule import fit_flow_rule, friction_closure, froude_eq47, mu_eq50
from .hstop import (compare_hstop_forms, fit_hstop, fit_hstop_eq38, hstop_eq38, hstop_eq45,
                    hstop_intervals_from_runs, theta_stop_eq38, theta_stop_eq45)
from .identify import assess
from .result import FitResult, error_eq49, failed_fit
from .rheology import fit_mu_I, inertial_number, mu_of_I
from .segregation import (Ps_teq29, asymmetric_flux_amplitude, combine_Ps_runs,
                          compare_segregation_models, fit_asymmetric_flux, fit_Ps, fit_Ps_law,
                          phi_asymmetric, phi_teq28)
from .shape_factor import (alpha_by_theta, alpha_eq54, alpha_eq55, fit_alpha,
                           fit_alpha_basal_layer, fit_alpha_constant, velocity_profile_eq54)
from .table import (CAMPAIGN_COLUMNS, FLOW_STATES, campaign_table_from_records,
                    empty_campaign_table, select_runs, validate_campaign_table)

__all__ = [
    "FitResult", "error_eq49", "failed_fit", "assess",
    "CAMPAIGN_COLUMNS", "FLOW_STATES", "campaign_table_from_records", "empty_campaign_table",
    "select_runs", "validate_campaign_table",
    "hstop_eq45", "hstop_eq38", "theta_stop_eq45", "theta_stop_eq38", "hstop_intervals_from_runs",
    "fit_hstop", "fit_hstop_eq38", "compare_hstop_forms",
    "froude_eq47", "mu_eq50", "fit_flow_rule", "friction_closure",
    "density_eq52", "stress_ratio_eq53", "fit_bulk_density", "fit_stress_ratio",
    "alpha_by_theta", "alpha_eq54", "alpha_eq55", "velocity_profile_eq54", "fit_alpha",
    "fit_alpha_basal_layer", "fit_alpha_constant",
    "phi_teq28", "phi_asymmetric", "asymmetric_flux_amplitude", "Ps_teq29", "fit_Ps",
    "fit_asymmetric_flux", "fit_Ps_law", "compare_segregation_models", "combine_Ps_runs",
    "mu_of_I", "inertial_number", "fit_mu_I", "fit_campaign", "DisorderedWindow",
]
