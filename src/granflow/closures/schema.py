"""Layout of a granflow closure library: which closures it holds and how they are named.

Each closure *kind* (the ``kind`` of a :class:`granflow.fitting.FitResult`) is stored over the
dimensions in :data:`KINDS` (``contact_law``, ``lambda`` for the basal roughness, ``sigma`` for the
size ratio) as these variables, every one with CF ``units`` and ``long_name``:

* ``<kind>_<param>`` and ``<kind>_<param>_stderr`` -- fitted parameter and its standard error;
* ``<kind>_error`` -- the fit's error measure (Weinhart et al. 2012 Eq. 49 of its residuals);
* ``<kind>_ok`` (int8 flag 0/1: 1 only when every parameter of the stored form is identified
  and no held-out run contradicts it), ``<kind>_status`` (ok, reduced, unidentified, misfit,
  failed), ``<kind>_form`` (full or the name of a stated reduced form), ``<kind>_n_points``,
  ``<kind>_message``, ``<kind>_selection`` (which runs entered and why others did not);
* ``<kind>_<param>_status`` / ``_reason`` -- identified, unidentified, fixed or not_in_form, and
  why (:mod:`granflow.fitting.identify`);
* ``<kind>_<param>_data_lower_bound`` / ``_data_upper_bound`` (only where some fit has one) --
  the one-sided 95 % bound the data give a parameter whose bootstrap refits an optimiser bound
  limits on the other side (:func:`granflow.fitting.result.data_bound`): its value and stderr
  are then the bound's, not the data's, and this is what the data do show;
* ``<kind>_ensemble_<param>`` (dim ``sample``) -- bootstrap refits or covariance draws, from
  which evaluators compute the uncertainty of an evaluated closure;
* ``<kind>_heldout_max_abs_z``, ``<kind>_chi2_dof``, ``<kind>_birge_ratio`` -- fit diagnostics;
  per run ``campaign_used_by_<kind>`` (int8) and ``campaign_heldout_z_<kind>``;
* ``<kind>_<var>_min`` / ``_max`` -- range of the data the fit saw (evaluators refuse to leave it
  unless asked to extrapolate);
* declared extras, e.g. ``segregation_Ps_ci95_low/high``.

The campaign table travels along on a ``run`` dimension as ``campaign_<column>``.  Strings are
stored as UTF-8 character arrays (since schema 2.1; xarray reads them back as strings).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .. import units as U

SCHEMA_NAME = "granflow.closures"
#: 2.1: strings are stored as character arrays (2.0: variable-length strings); the same data
SCHEMA_VERSION = "2.1"
LAMBDA_DIM = "lambda"
CONTACT_LAW_DIM = "contact_law"
SIGMA_DIM = "sigma"
RUN_DIM = "run"
SAMPLE_DIM = "sample"
CAMPAIGN_PREFIX = "campaign_"

#: FitResult.coords key -> library dimension
COORD_TO_DIM = {"lam": LAMBDA_DIM, "contact_law": CONTACT_LAW_DIM, "sigma": SIGMA_DIM}


@dataclass(frozen=True)
class KindSpec:
    """How one closure kind is stored: dimensions, parameter units/names, ranges, extras."""

    dims: tuple
    equation: str
    params: dict          # name -> (units, long_name)
    error_units: str
    ranges: dict          # variable -> (units, long_name)
    extras: dict = field(default_factory=dict)  # extra key -> (units, long_name)


_ANGLE_RANGE = {"theta": (U.ANGLE, "inclination theta")}
_H_RANGE = {"h": (U.LENGTH, "flow height h")}
_HSTOP_PARAMS = {
    "delta1": (U.ANGLE, "hstop angle delta1 (minimum inclination of steady flow)"),
    "delta2": (U.ANGLE, "hstop angle delta2 (inclination where hstop vanishes)"),
    "A": (U.LENGTH, "hstop length scale A"),
}
_FLOW_RULE_PARAMS = {
    "beta": (U.DIMENSIONLESS, "flow-rule slope beta"),
    "gamma": (U.DIMENSIONLESS, "flow-rule offset gamma"),
}

#: the random effect of :func:`granflow.fitting.hstop.base_scatter` (brackets on several bases)
_BASE_SIGMA = (U.ANGLE, "standard deviation of an hstop offset common to one base realisation's "
                        "brackets (random effect in the bootstrap; NaN, or no such variable: all "
                        "brackets on one base)")

#: how many bootstrap refits stand behind a closure's stderrs (a fit refits beyond the
#: requested number until its identifiability tests are decided)
_REFITS = (U.DIMENSIONLESS, "number of bootstrap refits behind the standard errors (more than "
                            "requested until every identifiability test was decided, "
                            "granflow.fitting.result.bootstrap_undecided)")

KINDS = {
    "hstop": KindSpec(
        (CONTACT_LAW_DIM, LAMBDA_DIM), "Weinhart et al. 2012 Eq. (45)", _HSTOP_PARAMS, U.ANGLE,
        {**_ANGLE_RANGE, "h": (U.LENGTH, "height H")},
        {"max_distance": (U.ANGLE, "largest horizontal distance of the curve to an interval"),
         "base_sigma_between": _BASE_SIGMA, "bootstrap_refits": _REFITS}),
    "hstop_eq38": KindSpec(
        (CONTACT_LAW_DIM, LAMBDA_DIM), "Weinhart et al. 2012 Eq. (38)", _HSTOP_PARAMS, U.ANGLE,
        {**_ANGLE_RANGE, "h": (U.LENGTH, "height H")},
        {"max_distance": (U.ANGLE, "largest horizontal distance of the curve to an interval"),
         "base_sigma_between": _BASE_SIGMA, "bootstrap_refits": _REFITS}),
    "flow_rule": KindSpec(
        (CONTACT_LAW_DIM, LAMBDA_DIM), "Weinhart et al. 2012 Eq. (47)", _FLOW_RULE_PARAMS,
        U.DIMENSIONLESS,
        {**_ANGLE_RANGE, **_H_RANGE, "F": (U.DIMENSIONLESS, "Froude number F")},
        {"bootstrap_refits": _REFITS}),
    "friction": KindSpec(
        (CONTACT_LAW_DIM, LAMBDA_DIM), "Weinhart et al. 2012 Eq. (50)",
        {**_HSTOP_PARAMS, **_FLOW_RULE_PARAMS}, U.DIMENSIONLESS,
        {**_ANGLE_RANGE, **_H_RANGE, "F": (U.DIMENSIONLESS, "Froude number F")}),
    "alpha": KindSpec(
        (CONTACT_LAW_DIM, LAMBDA_DIM), "Weinhart et al. 2012 Eq. (54), (55)",
        {"d_lambda": (U.DIMENSIONLESS, "basal-layer coefficient d_lambda (Eq. 54c)"),
         "alpha_constant": (U.DIMENSIONLESS, "constant shape factor alpha(lambda) (Eq. 55)")},
        U.DIMENSIONLESS, {**_ANGLE_RANGE, **_H_RANGE}, {"bootstrap_refits": _REFITS}),
    "density": KindSpec(
        (CONTACT_LAW_DIM,), "Weinhart et al. 2012 Eq. (52)",
        {"c0": (U.DIMENSIONLESS, "bulk volume fraction coefficient c0"),
         "c1": (U.ANGLE, "bulk volume fraction angle scale c1"),
         "c2": (U.ANGLE, "bulk volume fraction angle offset c2"),
         "nu_ref": (U.DIMENSIONLESS, "bulk volume fraction at theta_ref (reduced forms)"),
         "dnu_dtheta": (U.PER_DEGREE, "slope of the bulk volume fraction with theta "
                                      "(linear reduced form)")},
        U.DIMENSIONLESS, dict(_ANGLE_RANGE),
        {"rho_p": (U.DENSITY, "particle material density rho_p"),
         "theta_ref": (U.ANGLE, "reference inclination of the reduced forms")}),
    "stress_ratio": KindSpec(
        (CONTACT_LAW_DIM,), "Weinhart et al. 2012 Eq. (53)",
        {"d0": (U.ANGLE, "stress-ratio angle scale d0"),
         "d1": (U.ANGLE, "stress-ratio angle offset d1"),
         "K_ref": (U.DIMENSIONLESS, "constant stress ratio (reduced form)")},
        U.DIMENSIONLESS, dict(_ANGLE_RANGE)),
    "segregation": KindSpec(
        (CONTACT_LAW_DIM, SIGMA_DIM), "Thornton et al. T-eq. (28)",
        {"Ps": (U.DIMENSIONLESS, "segregation Peclet number Ps")}, U.DIMENSIONLESS,
        {"z": (U.DIMENSIONLESS, "scaled depth z")},
        {"phi0": (U.DIMENSIONLESS, "mean small-particle volume fraction phi0"),
         "ci95": (U.DIMENSIONLESS, "95% confidence interval of Ps"),
         "scaled_depth": (U.LENGTH, "depth s - b of Eq. (42) over which z is scaled to [0, 1] "
                                    "(Ps is per unit scaled depth)"),
         # several runs at one ratio (replicates, starts): granflow.fitting.combine_Ps_runs
         "runs_combined": (U.DIMENSIONLESS, "number of runs whose Ps is averaged at this size "
                                            "ratio (NaN: one run)"),
         "Ps_between_run_sd": (U.DIMENSIONLESS, "standard deviation of Ps between the runs at "
                                                "this size ratio (seeds, starts)"),
         "Ps_within_run_sem": (U.DIMENSIONLESS, "standard error of the runs' mean Ps from their "
                                                "own window errors alone (compare with "
                                                "segregation_Ps_stderr)"),
         # a run's own error is the larger of these two (granflow.campaign.collect)
         "Ps_windows_sem": (U.DIMENSIONLESS, "standard error of Ps from the run's decorrelated "
                                             "profile windows (several runs: rms / sqrt(n))"),
         "Ps_wander_sd": (U.DIMENSIONLESS, "wander of a profile window's Ps in time at the run's "
                                           "number of flow particles, C Ps / sqrt(N), measured "
                                           "on long runs (several runs: rms / sqrt(n))")}),
    "segregation_asymmetric": KindSpec(
        (CONTACT_LAW_DIM, SIGMA_DIM), "Gajjar & Gray 2014 asymmetric flux (seed 001 Eq. 2.9)",
        {"Ps": (U.DIMENSIONLESS, "segregation Peclet number Ps (asymmetric flux)"),
         "kappa": (U.DIMENSIONLESS, "flux asymmetry kappa")}, U.DIMENSIONLESS,
        {"z": (U.DIMENSIONLESS, "scaled depth z")},
        {"phi0": (U.DIMENSIONLESS, "mean small-particle volume fraction phi0")}),
    "Ps_law": KindSpec(
        (CONTACT_LAW_DIM,), "Thornton et al. T-eq. (29)",
        {"Pmax": (U.DIMENSIONLESS, "maximum Peclet number Pmax"),
         "k": (U.DIMENSIONLESS, "Peclet-number growth rate k"),
         "slope": (U.DIMENSIONLESS, "initial slope dPs/d(1/sigma) (linear reduced form)")},
        U.DIMENSIONLESS, {"sigma": (U.DIMENSIONLESS, "size ratio sigma")},
        {"Pmax_lower_bound": (U.DIMENSIONLESS, "one-sided 95 % lower bound on Pmax from the "
                                               "largest measured Ps"),
         "k_lower_bound": (U.DIMENSIONLESS, "95 % lower bound on k where T-eq. 29 is reduced "
                                            "(saturated sweep; runs bracketing their steady Ps)"),
         "k_upper_bound": (U.DIMENSIONLESS, "95 % upper bound on k where T-eq. 29 is reduced, "
                                            "from every run's interval (inf: none)")}),
    "mu_I": KindSpec(
        (CONTACT_LAW_DIM,), "seed 001 Eq. (2.13)",
        {"mu_s": (U.DIMENSIONLESS, "static friction mu_s"),
         "mu_d": (U.DIMENSIONLESS, "dynamic friction mu_d"),
         "I0": (U.DIMENSIONLESS, "reference inertial number I0")}, U.DIMENSIONLESS,
        {"I": (U.DIMENSIONLESS, "inertial number I")}),
    # self-diffusion normal to the base of tagged particles in steady flow (granflow.coarse.
    # diffusion), for the time scale of the segregation-remixing equation (T-eq. 27)
    "diffusivity": KindSpec(
        (CONTACT_LAW_DIM,), "self-diffusion D = c_D (u_bar/h) d^2 (shear-rate scaling)",
        {"c_D": (U.DIMENSIONLESS, "self-diffusion coefficient c_D = D h / (u_bar d^2)")},
        U.DIFFUSIVITY,
        {"h": (U.LENGTH, "flow height h"), "u_bar": (U.VELOCITY, "depth-averaged velocity"),
         **_ANGLE_RANGE}),
}
