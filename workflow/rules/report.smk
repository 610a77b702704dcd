# The campaign report: notebooks/campaign_report.py (jupytext percent script) executed with
# nbclient into results/<campaign>/report.html (+ the executed .ipynb and the figures as PNG,
# which Snakemake's own --report lists next to the library).  The notebook is found through the
# shell prefix's $GRANFLOW_REPORT_NOTEBOOK (common.smk) and tracked by its content hash.

import hashlib


rule report:
    input:
        library=f"{RESULTS}/closures.nc",
        manifest=f"{RESULTS}/closures.json",
        fits=f"{RESULTS}/fits.json",
        table=f"{RESULTS}/campaign_table.nc",
        segregation=f"{RESULTS}/segregation_fits.json",
    output:
        html=report(
            f"{RESULTS}/report.html",
            category="Report",
            caption=str(REPO / "workflow" / "report" / "report.rst"),
        ),
        ipynb=f"{RESULTS}/report.ipynb",
        figures=report(
            directory(f"{RESULTS}/figures"),
            patterns=["{figure}.png"],
            category="Figures",
            caption=str(REPO / "workflow" / "report" / "figure.rst"),
        ),
    log:
        f"{RESULTS}/logs/report.log",
    params:
        notebook_sha256=hashlib.sha256(REPORT_NOTEBOOK.read_bytes()).hexdigest(),
        results=lambda wc, input: os.path.dirname(input.library),
        campaign=NAME,
        timeout=REPORT_TIMEOUT,
    threads: 1
    resources:
        **cluster_resources("report"),
    conda:
        CONDA_ENV
    shell:
        'granflow campaign report --notebook "$GRANFLOW_REPORT_NOTEBOOK" --results {params.results}'
        " --campaign {params.campaign} --out-html {output.html} --out-ipynb {output.ipynb}"
        " --figures {output.figures} --timeout {params.timeout} > {log} 2>&1"
