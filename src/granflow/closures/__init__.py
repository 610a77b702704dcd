"""Versioned netCDF closure libraries and vectorised closure evaluators.

* :func:`write_library` / :func:`open_library` -- write a new ``<name>-v<N>.nc`` version from
  :class:`granflow.fitting.FitResult` objects and the campaign table; read and verify one.
* Evaluators (Weinhart et al. 2012 Eq. 45, 47, 50, 52-55; Thornton et al. T-eq. 29; mu(I)):
  :func:`hstop`, :func:`froude`, :func:`mu`, :func:`alpha`, :func:`K`, :func:`density`,
  :func:`Ps`, :func:`mu_I` -- numpy or xarray input, ValueError outside the fitted range unless
  ``extrapolate=True``. Also available as ``ds.closures.<name>(...)``.
* :func:`compare_libraries` / :func:`format_comparison` -- parameter-by-parameter comparison.
"""

from .compare import compare_libraries, format_comparison
from .evaluate import (K, Ps, alpha, closure_parameters, closure_status, density, diffusivity,
                       froude, hstop, mu, mu_I)
from .library import (build_library_dataset, campaign_table, content_hash, library_path,
                      library_versions, open_library, write_library)
from .schema import KINDS, SCHEMA_NAME, SCHEMA_VERSION

__all__ = [
    "write_library", "open_library", "build_library_dataset", "campaign_table", "content_hash",
    "library_path", "library_versions", "KINDS", "SCHEMA_NAME", "SCHEMA_VERSION",
    "hstop", "froude", "mu", "alpha", "K", "density", "Ps", "mu_I", "diffusivity",
    "closure_parameters",
    "compare_libraries", "format_comparison",
]
