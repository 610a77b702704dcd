"""Simulation campaigns: the glue between a campaign configuration and the Snakemake workflow.

A *campaign* (``config/config.yaml``) is a set of periodic chute runs -- the "chute" grid for the
closures of Weinhart et al. (2012) and a "segregation" sweep over size ratios (Thornton et al.)
-- plus, optionally, the paper's adaptive hstop search (§6).  This subpackage holds no physics; it

* expands the configuration into run points and readable run directories
  (:mod:`granflow.campaign.grid`: ``<campaign>/chute/<law>/lambda~1/theta~24/H~10``),
* validates configurations against ``workflow/schemas/config.schema.yaml`` with messages that
  name the key and its allowed range (:mod:`granflow.campaign.config`),
* derives one campaign-table row per finished run, collects the table, runs every closure fit
  and writes the versioned closure library (:mod:`granflow.campaign.collect`,
  :mod:`granflow.campaign.fits`, :mod:`granflow.campaign.library`),
* steps the adaptive hstop search as a Snakemake checkpoint (:mod:`granflow.campaign.hstop`),
* executes the report notebook into HTML (:mod:`granflow.campaign.report`).

The workflow rules call these through ``granflow campaign <command>``
(:mod:`granflow.campaign.commands`).
"""

from .grid import (RunPoint, base_path, expand_runs, format_value, parse_run_path, run_params,
                   run_path)

__all__ = ["RunPoint", "base_path", "expand_runs", "format_value", "parse_run_path", "run_params",
           "run_path"]
