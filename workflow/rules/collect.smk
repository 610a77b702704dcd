# The campaign table: one row per run (grid runs and hstop-search runs), as netCDF with CF
# attributes and as CSV, plus the runs that could not enter it and the per-run segregation fits.


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
        gf=GRANFLOW,
        campaign=NAME,
    threads: 1
    resources:
        runtime=10,
        mem_mb=2000,
    conda:
        CONDA_ENV
    shell:
        "{params.gf} campaign collect {input.rows} --campaign {params.campaign}"
        " --out-nc {output.nc} --out-csv {output.csv} --excluded {output.excluded}"
        " --segregation {output.segregation} > {log} 2>&1"
