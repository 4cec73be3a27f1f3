# Stages "compare", "diagnose" and "ledger": each model variant against each identification run, the
# effect the variant lacks, and the misfit across variants (the diagnosis loop).


rule compare:
    input:
        frf="results/{machine}/frf/{run}/frf.parquet",
        machine="results/{machine}/model/{variant}/machine.yaml",
    output:
        errors="results/{machine}/compare/{run}/{variant}/errors.parquet",
        summary="results/{machine}/compare/{run}/{variant}/summary.tsv",
        bode="results/{machine}/compare/{run}/{variant}/figures/bode_compare.png",
        error_map="results/{machine}/compare/{run}/{variant}/figures/error_map.png",
        findings="results/{machine}/compare/{run}/{variant}/findings.tsv",
    log:
        "logs/{machine}/compare_{run}_{variant}.log",
    benchmark:
        "logs/{machine}/compare_{run}_{variant}.benchmark.tsv"
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        settings=config["compare"],
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: model variant {wildcards.variant} against the measured FRFs"
    script:
        "../workflow/scripts/compare.py"


rule diagnose:
    input:
        unpack(diagnose_inputs),
    output:
        candidates="results/{machine}/diagnose/{run}/{variant}/candidates.tsv",
        joint="results/{machine}/diagnose/{run}/{variant}/joint.tsv",
        cells="results/{machine}/diagnose/{run}/{variant}/cells.tsv",
        findings="results/{machine}/diagnose/{run}/{variant}/findings.tsv",
        verdict="results/{machine}/diagnose/{run}/{variant}/verdict.tsv",
        text="results/{machine}/diagnose/{run}/{variant}/diagnosis.md",
        fingerprint="results/{machine}/diagnose/{run}/{variant}/figures/fingerprint.png",
    log:
        "logs/{machine}/diagnose_{run}_{variant}.log",
    benchmark:
        "logs/{machine}/diagnose_{run}_{variant}.benchmark.tsv"
    priority: diagnose_priority  # the longest jobs, before the comparisons and figures that fill the gaps
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        compare=config["compare"],
        settings=config["diagnose"],
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: which effect model variant {wildcards.variant} is missing"
    script:
        "../workflow/scripts/diagnose.py"


rule ledger:
    input:
        summaries=lambda wildcards: [
            f"results/{wildcards.machine}/compare/{run}/{variant}/summary.tsv"
            for run in runs_of_machine(wildcards.machine)
            for variant in variants_of(wildcards.machine)
        ],
        verdicts=lambda wildcards: [
            f"results/{wildcards.machine}/diagnose/{run}/{variant}/verdict.tsv"
            for run in runs_of_machine(wildcards.machine)
            for variant in variants_of(wildcards.machine)
        ],
    output:
        ledger="results/{machine}/ledger/ledger.parquet",
        table="results/{machine}/ledger/ledger.tsv",
        figure="results/{machine}/ledger/figures/ledger.png",
        maps="results/{machine}/ledger/figures/excess_maps.png",
    log:
        "logs/{machine}/ledger.log",
    benchmark:
        "logs/{machine}/ledger.benchmark.tsv"
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        runs=lambda wildcards: [
            run for run in runs_of_machine(wildcards.machine) for _ in variants_of(wildcards.machine)
        ],
        variants=lambda wildcards: [
            v for _ in runs_of_machine(wildcards.machine) for v in variants_of(wildcards.machine)
        ],
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine}: the misfit of every model variant (ledger)"
    script:
        "../workflow/scripts/ledger.py"
