# Stage "update": rotor model update from the measured resonances and anti-resonances (thesis ch. 5.2).


rule update:
    input:
        unpack(update_inputs),
    output:
        comparison="results/{machine}/update/{run}/comparison.parquet",
        comparison_table="results/{machine}/update/{run}/comparison.tsv",
        variables="results/{machine}/update/{run}/variables.tsv",
        correlation="results/{machine}/update/{run}/correlation.tsv",
        mode_shapes="results/{machine}/update/{run}/mode_shapes.tsv",
        history="results/{machine}/update/{run}/history.parquet",
        machine="results/{machine}/update/{run}/machine.yaml",
        bode="results/{machine}/update/{run}/figures/bode_update.png",
        modulus="results/{machine}/update/{run}/figures/youngs_modulus.png",
        convergence="results/{machine}/update/{run}/figures/convergence.png",
    log:
        "logs/{machine}/update_{run}.log",
    benchmark:
        "logs/{machine}/update_{run}.benchmark.tsv"
    priority: 3  # before the comparisons: the measurement chain the model variants wait for
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        machine_config=machine_config,
        machine_update=lambda wildcards: config["machines"][wildcards.machine].get("update", {}),
        run_modes=lambda wildcards: RUNS[(wildcards.machine, wildcards.run)].get("update_modes"),
        settings=config["update"],
        fit_settings=config["fit"],  # the estimator whose bias the update takes off (ambid.update.estimator_bias)
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: rotor model update (thesis ch. 5.2)"
    script:
        "../workflow/scripts/update.py"
