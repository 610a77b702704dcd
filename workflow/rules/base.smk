# Rough bases: prepared once per (lambda, box) and reused by every run over them
# (Weinhart et al. 2012 §5: settle a layer of diameter-lambda particles, keep a band, freeze it).


rule base:
    output:
        f"{RESULTS}/bases/lambda~{{lam}}/box~{{Lx}}x{{Ly}}/base.npy",
    log:
        f"{RESULTS}/logs/base/lambda~{{lam}}_box~{{Lx}}x{{Ly}}.log",
    params:
        gf=GRANFLOW,
        layers=G.base_settings(config)["layers"],
        settle=G.base_settings(config)["settle_time"],
        seed=G.base_settings(config)["seed"],
    threads: 1
    resources:
        **cluster_resources("base"),
    conda:
        CONDA_ENV
    shell:
        "{params.gf} -v prepare-base --lam {wildcards.lam} --Lx {wildcards.Lx}"
        " --Ly {wildcards.Ly} --seed {params.seed} --base-layers {params.layers}"
        " --settle-time {params.settle} --out {output} > {log} 2>&1"
