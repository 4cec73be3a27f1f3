# Stage "report": one self-contained HTML page per machine, every stage's figures and tables in thesis order.

# caption templates, passed by content: a changed caption re-renders the reports
CAPTIONS = {path.stem: path.read_text() for path in sorted(Path(workflow.basedir, "workflow", "report").glob("*.md"))}


rule report:
    input:
        lambda wildcards: machine_outputs(wildcards.machine),
    output:
        report="results/{machine}/report.html",
    log:
        "logs/{machine}/report.log",
    benchmark:
        "logs/{machine}/report.benchmark.tsv"
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        calibration_runs=lambda wildcards: runs_of_machine(wildcards.machine, "calibration"),
        identification_runs=lambda wildcards: runs_of_machine(wildcards.machine),
        multisine_runs=lambda wildcards: [r for m, r in identification_runs("multisine") if m == wildcards.machine],
        variants=lambda wildcards: variants_of(wildcards.machine),
        commissioning_runs=lambda wildcards: commissioning_runs(wildcards.machine),
        updated=lambda wildcards: bool(config["machines"][wildcards.machine].get("update")),
        captions=CAPTIONS,
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine}: the HTML report"
    script:
        "../workflow/scripts/report.py"
