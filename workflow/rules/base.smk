# Rough bases: prepared once per (lambda, box) and reused by every run over them, made as the
# config's `base:` says (pile thickness, settling time and friction, fill, kept band)
# (Weinhart et al. 2012 §5: settle a layer of diameter-lambda particles, keep a band, freeze it).


_BASE = G.base_settings(config)
# how every base of the campaign is made (the campaign's base and those of replicate_bases)
BASE_MAKING = dict(layers=_BASE["layers"], settle=_BASE["settle_time"], mu=_BASE["settle_mu_c"],
                   fill=_BASE["fill_packing"], band=_BASE["band"])
PREPARE_BASE = (
    "granflow -v prepare-base --lam {wildcards.lam} --Lx {wildcards.Lx}"
    " --Ly {wildcards.Ly} --seed {params.seed} --base-layers {params.layers}"
    " --settle-time {params.settle} --settle-mu-c {params.mu} --fill-packing {params.fill}"
    " --band {params.band} --out {output} > {log} 2>&1"
)


rule base:
    # first, beside the compile-warm job (both cores busy from the start)
    priority: 100
    output:
        f"{RESULTS}/bases/lambda~{{lam}}/box~{{Lx}}x{{Ly}}/base.npy",
    log:
        f"{RESULTS}/logs/base/lambda~{{lam}}_box~{{Lx}}x{{Ly}}.log",
    params:
        seed=_BASE["seed"],
        **BASE_MAKING,
    threads: 1
    resources:
        **cluster_resources("base"),
    conda:
        CONDA_ENV
    shell:
        PREPARE_BASE


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
        seed=lambda wildcards: int(wildcards.bseed),
        **BASE_MAKING,
    threads: 1
    resources:
        **cluster_resources("base"),
    conda:
        CONDA_ENV
    shell:
        PREPARE_BASE


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
