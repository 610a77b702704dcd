"""Continuum models driven by a closure library (the consumers of the closures).

* :mod:`.uniform` -- uniform layer after a change of inclination: Weinhart et al. (2012)
  Eq. (34) reduced to du/dt = g cos(theta) (tan(theta) - mu(h, F)) with mu of Eq. (50);
  :func:`uniform_layer`, :func:`switch_prediction` (over the library's parameter ensemble),
  :func:`fit_relaxation`.
* :mod:`.column` -- the same friction law as a local rheology in a depth-resolved column
  (a mu(I)-type model, Jop et al. 2005): after a change of inclination the profile adjusts by
  shear, and the layer relaxes 5 / (2 lambda1) = 1.276 times more slowly than the ODE (linear
  theory, lambda1 from the first zero of J_(-1/3)): :func:`column_layer`, or
  ``switch_prediction(..., model="column")``.
* :mod:`.shallow` -- one-dimensional finite-volume solver of Eq. (34a-c) with mu(h, F), alpha
  and K from the library: :func:`shallow_layer`; optionally with the depth-averaged viscous
  stress of Gray & Edwards (2014) (``viscosity=``, nu from
  :meth:`FlowClosures.gray_edwards_viscosity`: no parameter beyond the library's).
* :mod:`.kinematic` -- the local-equilibrium limit of Eq. (34): mu(h, F) = tan(theta) - K dh/dx
  (diffusive wave) or = tan(theta) (kinematic wave), only the mass balance left:
  :func:`local_equilibrium_layer` (no parameter beyond the library's mu(h, F) and K).
* :mod:`.segregation` -- segregation and diffusive remixing in depth, Thornton et al. T-eq. (27)
  with the symmetric flux or the asymmetric flux of seed 001: :func:`segregation_layer`;
  :func:`fit_segregation_transient` fits its two rates S and D_r to a measured transient
  phi(z, t) (a particle run's, from :mod:`granflow.coarse.segregation_flux`).
* :mod:`.closures` -- :class:`FlowClosures`: a library's mu(h, F), alpha(h), K at one
  inclination as fast functions (status-checked; ensemble members for uncertainty), or
  synthetic closures (Coulomb friction) for tests.
* :mod:`.exact` -- exact solutions for tests (Mangeney et al. 2000 dam break).

Closures that are not ``ok``/``reduced``: the models' library entry points
(:meth:`FlowClosures.from_library`, :func:`switch_prediction`) take ``allow_unidentified``
(default False) and refuse such a closure with the library's own error naming it; with
``allow_unidentified=True`` it is used and its status is written into the result
(``closure_status_<kind>``), so a prediction built on an unidentified closure says so.
``failed`` closures are always refused.  The particle comparisons of :mod:`.experiments`
default to ``allow_unidentified=True`` (they test the campaign's closures as they are) and
record every status in their JSON.

Every model returns an :class:`xarray.Dataset` with CF attributes (units ``1`` and the scale in
``nondimensional_unit``; see :mod:`granflow.units`), provenance and the status/form of every
closure it used (``closure_status_friction`` etc.).

Example: open a library and run each model ::

    import numpy as np
    import granflow
    from granflow.closures import open_library
    from granflow.continuum import (FlowClosures, local_equilibrium_layer, segregation_layer,
                                    shallow_layer, switch_prediction)
    from granflow.continuum.experiments import segregation_Ps_at

    # the campaign's library with the diffusivity closure added (granflow.continuum.experiments
    # diffusivity; results/default/closures.nc alone has no diffusivity for model 3)
    lib = open_library("results/continuum/closures.nc")
    print(lib.closures.status()[["kind", "parameter", "status"]])
    # 1. a steady layer h = 8, u = 0.9 switched to 26 degrees (friction may be unidentified
    #    in a small campaign: allow_unidentified=True evaluates it anyway, and says so)
    pred = switch_prediction(lib, h=8.0, u0=0.9, theta=26.0, t_end=200.0,
                             allow_unidentified=True)
    pred.u_steady.sel(stat="value"), pred.tau.sel(stat="std")
    #    ... and as a depth-resolved column with the same closures (the profile adjusts too)
    col = switch_prediction(lib, h=8.0, u0=0.9, theta=26.0, t_end=200.0,
                            allow_unidentified=True, model="column")
    # 2. a bump travelling down a periodic chute of length 200
    c = FlowClosures.from_library(lib, 26.0, allow_unidentified=True)
    x = np.arange(400) * 0.5 + 0.25
    h0 = 7.0 + 2.0 * np.exp(-((x - 50.0) / 8.0) ** 2)
    u0 = c.steady_froude(h0) * np.sqrt(c.g_cos * h0)
    res = shallow_layer(c, x, h0, u0, t_end=100.0)
    #    ... in local equilibrium, the kinematic wave u = u_s(h) of the library's flow rule
    #    (the one model within 15 % of a particle bump's peak, README)
    res_kw = local_equilibrium_layer(c, x, h0, t_end=100.0, diffusive=False)
    #    ... and with the depth-averaged viscous stress (Gray & Edwards 2014), nu from the
    #    library's own flow rule at the mean depth
    res_v = shallow_layer(c, x, h0, u0, t_end=100.0,
                          viscosity=c.gray_edwards_viscosity(float(h0.mean())))
    # 3. segregation with the library's Ps and the measured diffusivity (in a mixture at the
    #    small diameter, as measured over segregation transients: experiments module docstring)
    D = float(lib.closures.diffusivity(u_bar=0.75, h=7.9, d_mean=1.0))
    Ps, Ps_status = segregation_Ps_at(lib, 0.5)   # refused unless ok/reduced
    seg = segregation_layer(Ps=Ps, D=D, h=7.9, phi0=0.5, t_end=400.0)
"""

from .closures import FlowClosures
from .column import column_layer
from .exact import dam_break_front, mangeney_dam_break
from .kinematic import equilibrium_froude, local_equilibrium_layer
from .segregation import fit_segregation_transient, segregation_layer
from .shallow import shallow_layer
from .uniform import fit_relaxation, linear_relaxation_time, switch_prediction, uniform_layer

__all__ = ["FlowClosures", "uniform_layer", "column_layer", "switch_prediction", "fit_relaxation",
           "linear_relaxation_time", "shallow_layer", "local_equilibrium_layer",
           "equilibrium_froude", "fit_segregation_transient", "segregation_layer",
           "mangeney_dam_break", "dam_break_front"]
