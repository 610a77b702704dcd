# Every closure fit of the campaign table (granflow.fitting.fit_campaign): hstop Eq. (45) and
# (38), flow rule Eq. (47), friction Eq. (50), alpha Eq. (54)/(55), bulk density Eq. (52),
# stress ratio Eq. (53), Ps(sigma) T-eq. (29); plus the per-run Ps fits (T-eq. 28).  Runs left
# undecided at their cap count as flowing for the hstop brackets (the paper's binary rule, §6).


rule fit:
    input:
        table=f"{RESULTS}/campaign_table.nc",
        segregation=f"{RESULTS}/segregation_fits.json",
        excluded=f"{RESULTS}/excluded_runs.csv",
    output:
        json=f"{RESULTS}/fits.json",
        csv=report(
            f"{RESULTS}/closures.csv",
            category="Closure library",
            caption=str(REPO / "workflow" / "report" / "closures.rst"),
        ),
    log:
        f"{RESULTS}/logs/fit.log",
    params:
        n_bootstrap=LIBRARY.get("n_bootstrap", 200),
        # Eq. 46/48: per lambda, the steady closures use only delta3(H) < theta < delta_acc
        windows=json.dumps({str(k): v for k, v in
                            (LIBRARY.get("disordered_window") or {}).items()}),
    threads: 1
    resources:
        **cluster_resources("fit"),
    conda:
        CONDA_ENV
    shell:
        "granflow campaign fit --table {input.table} --segregation {input.segregation}"
        " --excluded {input.excluded}"
        " --n-bootstrap {params.n_bootstrap} --windows-json {params.windows:q}"
        " --out-json {output.json} --out-csv {output.csv}"
        " > {log} 2>&1"
