# Coarse-graining and classification run inside each simulate job (on the fly, see
# simulate.smk).  This stage reads their products -- summary.json (flow state, depth averages
# with time-window spreads) and profiles.nc -- into one campaign-table row per run, and for a
# bidisperse run fits the Peclet number Ps (Thornton et al. T-eq. 28) to its phi(z) profile.


rule row:
    input:
        summary=f"{RESULTS}/{{kind}}/{{law}}/{{point}}/summary.json",
        profiles=f"{RESULTS}/{{kind}}/{{law}}/{{point}}/profiles.nc",
    output:
        f"{RESULTS}/{{kind}}/{{law}}/{{point}}/row.json",
    log:
        f"{RESULTS}/{{kind}}/{{law}}/{{point}}/row.log",
    params:
        run_dir=dir_of,
        rel=lambda wc: f"{wc.kind}/{wc.law}/{wc.point}",
        window=SEG_WINDOW,
    threads: 1
    resources:
        **cluster_resources("row"),
    conda:
        CONDA_ENV
    shell:
        "granflow campaign row {params.run_dir} --rel {params.rel}"
        " --segregation-window {params.window} --out {output} > {log} 2>&1"
