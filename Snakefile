# granflow campaign workflow: parameter grid -> runs (coarse-grained and classified on the fly)
# -> campaign table -> closure fits -> versioned closure library -> executed report.
#
#   snakemake --cores 2                                   # the default campaign (config/config.yaml)
#   snakemake --cores 2 --configfile config/weinhart2012.yaml   # the paper's protocol (cluster!)
#   snakemake --workflow-profile profiles/slurm           # on a Slurm cluster
#   snakemake --report results/report.zip                 # Snakemake's own report
#
# Rules call the `granflow` command line (granflow simulate / prepare-base / campaign ...);
# no physics lives in this workflow.  See README.md, "Campaign workflow".

import json
import os
from pathlib import Path

from snakemake.utils import min_version, validate

min_version("8.0")

REPO = Path(workflow.basedir)


configfile: os.path.join(workflow.basedir, "config", "config.yaml")


# Validation before any job: granflow's checker names the key and its allowed range (and adds
# cross-field checks); snakemake.utils.validate then checks the same schema again.
from granflow.campaign.config import check_config

SCHEMA = REPO / "workflow" / "schemas" / "config.schema.yaml"
check_config(config, SCHEMA)
validate(config, str(SCHEMA))

# a global numerics key that a --configfile changed but the default's campaign block still
# overrides (granflow.campaign.config.shadowed_numerics) is said before any job runs
from granflow.campaign.config import load_yaml, shadowed_numerics
from snakemake.logging import logger

for _msg in shadowed_numerics(config, load_yaml(REPO / "config" / "config.yaml")):
    logger.warning(f"granflow config: {_msg}")

# ACDD attribution (creator, institution, license, ...) of every output: passed to the jobs in
# the environment, not as a parameter, so that changing it reruns no simulation
from granflow.cfconventions import ATTRIBUTION_ENV

os.environ[ATTRIBUTION_ENV] = json.dumps(config.get("metadata") or {}, sort_keys=True)


include: "workflow/rules/common.smk"
include: "workflow/rules/base.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/derive.smk"
include: "workflow/rules/hstop.smk"
include: "workflow/rules/collect.smk"
include: "workflow/rules/fit.smk"
include: "workflow/rules/library.smk"
include: "workflow/rules/report.smk"


onstart:
    # fit every rule's request to the partition before the first job is submitted: an
    # impossible request fails here with a message instead of a job pending forever
    if on_slurm():
        for _rule in CL.DEFAULT_RESOURCES:
            CLUSTER.fitted(_rule, True)
        for _msg in CLUSTER.messages:
            logger.warning(f"granflow cluster: {_msg}")
    else:
        hand_out_spare_cores()


rule all:
    input:
        final_targets(),
    default_target: True
