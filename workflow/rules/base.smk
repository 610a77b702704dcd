# Rough bases: prepared once per (lambda, box) and reused by every run over them, made as the
# config's `base:` says (pile thickness, settling time and friction, fill, kept band)
# (Weinhart et al. 2012 §5: settle a layer of diameter-lambda particles, keep a band, freeze it).


rule base:
    # first, beside the compile-warm job (both cores busy from the start)
    priority: 100
    output:
        f"{RESULTS}/bases/lambda~{{lam}}/box~{{Lx}}x{{Ly}}/base.npy",
    log:
        f"{RESULTS}/logs/base/lambda~{{lam}}_box~{{Lx}}x{{Ly}}.log",
    params:
        layers=G.base_settings(config)["layers"],
        settle=G.base_settings(config)["settle_time"],
        seed=G.base_settings(config)["seed"],
        mu=G.base_settings(config)["settle_mu_c"],
        fill=G.base_settings(config)["fill_packing"],
        band=G.base_settings(config)["band"],
    threads: 1
    resources:
        **cluster_resources("base"),
    conda:
        CONDA_ENV
    shell:
        "granflow -v prepare-base --lam {wildcards.lam} --Lx {wildcards.Lx}"
        " --Ly {wildcards.Ly} --seed {params.seed} --base-layers {params.layers}"
        " --settle-time {params.settle} --settle-mu-c {params.mu} --fill-packing {params.fill}"
        " --band {params.band} --out {output} > {log} 2>&1"


# Further bases of hstop_bisection.replicate_bases: replicate chain k of a height falls onto a
# base made the same way with seed base.seed + k (the scatter between base realisations)
rule base_replicate:
    priority: 100
    output:
        f"{RESULTS}/bases/lambda~{{lam}}/box~{{Lx}}x{{Ly}}/seed~{{bseed}}/base.npy",
    log:
        f"{RESULTS}/logs/base/lambda~{{lam}}_box~{{Lx}}x{{Ly}}_seed~{{bseed}}.log",
    wildcard_constraints:
        bseed="[0-9]+",
    params:
        layers=G.base_settings(config)["layers"],
        settle=G.base_settings(config)["settle_time"],
        mu=G.base_settings(config)["settle_mu_c"],
        fill=G.base_settings(config)["fill_packing"],
        band=G.base_settings(config)["band"],
    threads: 1
    resources:
        **cluster_resources("base"),
    conda:
        CONDA_ENV
    shell:
        "granflow -v prepare-base --lam {wildcards.lam} --Lx {wildcards.Lx}"
        " --Ly {wildcards.Ly} --seed {wildcards.bseed} --base-layers {params.layers}"
        " --settle-time {params.settle} --settle-mu-c {params.mu} --fill-packing {params.fill}"
        " --band {params.band} --out {output} > {log} 2>&1"


# Compile-warm: tiny runs of each (kind, contact law) of the campaign, beside the base job, so
# that the simulate jobs find numba's kernels cached instead of each compiling them (measured:
# ~90 s of both cores at the start of a fresh clone's default campaign).  No results kept;
# a final target (common.smk), not an input of the runs.
rule warm_engine:
    priority: 100
    output:
        WARM_ENGINE,
    log:
        f"{RESULTS}/logs/warm_engine.log",
    params:
        cfg=CONFIG_JSON,
    threads: 1
    resources:
        **cluster_resources("base"),
    conda:
        CONDA_ENV
    shell:
        "granflow -v campaign warm-engine --config-json {params.cfg:q} --out {output}"
        " > {log} 2>&1"
