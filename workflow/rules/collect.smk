# The campaign table: one row per run (grid runs and hstop-search runs), as netCDF with CF
# attributes and as CSV, plus the runs that could not enter it and the per-run segregation fits.
# The row list is passed through params (not {input.rows}): while the hstop checkpoint chain
# is unfinished (a dry run) Snakemake stands in the checkpoint for the input function's result,
# the job has no named input `rows`, and `snakemake -n` must still be able to format it.


rule collect:
    input:
        unpack(collect_inputs),
    output:
        nc=f"{RESULTS}/campaign_table.nc",
        csv=f"{RESULTS}/campaign_table.csv",
        excluded=f"{RESULTS}/excluded_runs.csv",
        segregation=f"{RESULTS}/segregation_fits.json",
    log:
        f"{RESULTS}/logs/collect.log",
    params:
        campaign=NAME,
        config=CONFIG_JSON,
        rows=lambda wc, input: " ".join(shlex.quote(str(f)) for f in input.get("rows", [])),
    threads: 1
    resources:
        **cluster_resources("collect"),
    conda:
        CONDA_ENV
    shell:
        "granflow campaign collect {params.rows} --campaign {params.campaign}"
        " --out-nc {output.nc} --out-csv {output.csv} --excluded {output.excluded}"
        " --segregation {output.segregation} --config-json {params.config:q} > {log} 2>&1"
