"""Steady-state detection, flow-state classification and early stopping (Weinhart et al. 2012 §6, §8).

* :mod:`.timeseries` -- statistical inefficiency, decorrelated subsampling, pymbar-style
  equilibration detection and serial-correlation-aware trend tests;
* :mod:`.classify` -- :func:`classify_flow`: arrested / steady / accelerating / layered /
  oscillating / undecided from the energy ratio E_kin/<E_ela> (§6, Fig. 3; §8, Fig. 10);
* :mod:`.monitor` -- :class:`SteadyStateMonitor`: incremental early stopping with the steady window
  start for the coarse-grained averages (§5: T = 100 after steady state, t <= 2000);
* :mod:`.hstop_search` -- the paper's adaptive (theta, H) walk bracketing h_stop(theta) (§6).
"""

from .classify import (FlowClassification, classify_flow, layered_state, layering_amplitude,
                       oscillation_cycles)
from .hstop_search import ARREST_HORIZON, HstopInterval, HstopSearch, is_flowing, run_hstop_search
from .monitor import MonitorDecision, SteadyStateMonitor
from .timeseries import (
    TrendResult,
    autocorrelation,
    curvature_test,
    detect_equilibration,
    standard_error_of_mean,
    statistical_inefficiency,
    subsample_indices,
    trend_test,
)

__all__ = [
    "ARREST_HORIZON",
    "FlowClassification",
    "HstopInterval",
    "HstopSearch",
    "MonitorDecision",
    "SteadyStateMonitor",
    "TrendResult",
    "autocorrelation",
    "classify_flow",
    "curvature_test",
    "detect_equilibration",
    "is_flowing",
    "layering_amplitude",
    "layered_state",
    "oscillation_cycles",
    "run_hstop_search",
    "standard_error_of_mean",
    "statistical_inefficiency",
    "subsample_indices",
    "trend_test",
]
