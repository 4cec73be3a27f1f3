# Stage "fit": parametric models of the FRFs, resonances and anti-resonances (thesis ch. 5.1).


rule fit:
    input:
        frf="results/{machine}/frf/{run}/frf.parquet",
        machine=machine_model_file,
    output:
        features="results/{machine}/fit/{run}/features.parquet",
        table="results/{machine}/fit/{run}/features.tsv",
        findings="results/{machine}/fit/{run}/findings.tsv",
        models="results/{machine}/fit/{run}/models.parquet",
        bode="results/{machine}/fit/{run}/figures/bode_fit.png",
        stabilization="results/{machine}/fit/{run}/figures/stabilization.png",
    log:
        "logs/{machine}/fit_{run}.log",
    benchmark:
        "logs/{machine}/fit_{run}.benchmark.tsv"
    priority: 3  # before the comparisons: the measurement chain the model variants wait for
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        machine_config=machine_config,
        settings=config["fit"],
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: parametric fits, resonances and anti-resonances (thesis ch. 5.1)"
    script:
        "../workflow/scripts/fit.py"
