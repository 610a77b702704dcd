# The versioned closure library.  `granflow campaign library` builds the library and, if a
# version with the same content hash already exists in the library folder, reuses it;
# otherwise it writes the next version <name>-v<N>.nc (never overwriting one).  The rule's
# outputs are the fixed path results/<campaign>/closures.nc, a copy of the chosen version, and
# closures.json naming it.  So a rerun after a killed job (which resumes to identical numbers)
# or a forced rerun gives the same content and no new version; changed data give version N+1.


rule library:
    input:
        fits=f"{RESULTS}/fits.json",
        table=f"{RESULTS}/campaign_table.nc",
        excluded=f"{RESULTS}/excluded_runs.csv",
    output:
        nc=report(
            f"{RESULTS}/closures.nc",
            category="Closure library",
            caption=str(REPO / "workflow" / "report" / "library.rst"),
        ),
        manifest=f"{RESULTS}/closures.json",
    log:
        f"{RESULTS}/logs/library.log",
    params:
        dir=LIBRARY_DIR,
        name=LIBRARY["name"],
        note=(f"--reductions {shlex.quote(LIBRARY['reductions'])}"
              if LIBRARY.get("reductions") else ""),
        campaign=NAME,
        config=CONFIG_JSON,
    threads: 1
    resources:
        **cluster_resources("library"),
    conda:
        CONDA_ENV
    shell:
        "granflow campaign library --fits {input.fits} --table {input.table}"
        " --excluded {input.excluded}"
        " --dir {params.dir} --name {params.name} {params.note}"
        " --campaign {params.campaign} --config-json {params.config:q}"
        " --out {output.nc} --manifest {output.manifest} > {log} 2>&1"
