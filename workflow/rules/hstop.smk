# The adaptive hstop search of Weinhart et al. (2012) §6 as a chain of checkpoint steps, next
# to the plain grids.  Step 0 writes the initial walk state; step i reads state i-1, waits for
# the run at the point it proposed (an ordinary run directory, simulated by rule `simulate` and
# shared with the grid), records its flow state and writes state i.  The chain ends at the
# first state without a next point (helpers: hstop_* in common.smk).  Enable it with
# campaigns.chute.hstop_search.enabled.


checkpoint hstop_step:
    input:
        unpack(hstop_step_input),
    output:
        f"{RESULTS}/hstop/{{law}}/lambda~{{lam}}/step~{{i}}.json",
    log:
        f"{RESULTS}/hstop/{{law}}/lambda~{{lam}}/step~{{i}}.log",
    params:
        args=hstop_step_args,
    # the search is sequential: its next step is placed as soon as its run ends
    priority: 1
    localrule: True
    conda:
        CONDA_ENV
    shell:
        "granflow campaign hstop-step --law {wildcards.law} --lam {wildcards.lam}"
        " {params.args} --out {output} > {log} 2>&1"


# Concurrent hstop bisection chains (campaigns.chute.hstop_bisection): one chain per (law,
# lambda, filling height H, replicate k), each a sequence of checkpoint steps like the search
# above (replicate k: bracket runs with insertion seed + k, directories .../seed~k).  Step 0
# writes the initial state (first angle: the prior curve's theta_stop(H)); step i records the
# flow state of the bracket run state i-1 proposed (bracket/<law>/lambda~L/theta~T/H~H, a chute
# run that stops as soon as it is decisively flowing) and proposes the next angle, until the
# bracket is `tolerance` wide.  Chains at different H are independent, so they run side by side:
# rule hstop_bisect_chain gives each chain a file of fixed name (its final state) that the final
# targets list, so that every chain enters the DAG at once.


checkpoint hstop_bisect_step:
    input:
        unpack(bisect_step_input),
    output:
        f"{RESULTS}/hstop/{{law}}/lambda~{{lam}}/bisect/H~{{H}}/rep~{{k}}/step~{{i}}.json",
    log:
        f"{RESULTS}/hstop/{{law}}/lambda~{{lam}}/bisect/H~{{H}}/rep~{{k}}/step~{{i}}.log",
    params:
        args=bisect_step_args,
    # a chain's next step is placed as soon as its run ends (the chains are sequential)
    priority: 1
    localrule: True
    conda:
        CONDA_ENV
    shell:
        "granflow campaign hstop-bisect --law {wildcards.law} --lam {wildcards.lam}"
        " --H {wildcards.H} --replicate {wildcards.k} {params.args} --out {output} > {log} 2>&1"


rule hstop_bisect_chain:
    input:
        unpack(bisect_chain_input),
    output:
        f"{RESULTS}/hstop/{{law}}/lambda~{{lam}}/bisect/H~{{H}}/rep~{{k}}/chain.json",
    log:
        f"{RESULTS}/hstop/{{law}}/lambda~{{lam}}/bisect/H~{{H}}/rep~{{k}}/chain.log",
    params:
        # via params, as in rule collect: in a dry run the unfinished chain has no `state` yet
        state=lambda wc, input: input.get("state", ""),
    localrule: True
    conda:
        CONDA_ENV
    shell:
        "cp {params.state} {output} > {log} 2>&1"
