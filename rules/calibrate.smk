# Stage "calibrate": the magnetic center recomputed from the calibration log alone (thesis ch. 3, 6.1).


rule calibrate:
    input:
        log="data/{machine}/{run}/calibration.parquet",
        machine=machine_model_file,
    output:
        offsets="results/{machine}/calibration/{run}/offsets.tsv",
        pairs="results/{machine}/calibration/{run}/pairs.tsv",
        repeatability="results/{machine}/calibration/{run}/repeatability.tsv",
        result="results/{machine}/calibration/{run}/magnetic_center.tsv",
        stiffness="results/{machine}/calibration/{run}/stiffness.tsv",
        operating_point="results/{machine}/calibration/{run}/operating_point.yaml",
        convergence="results/{machine}/calibration/{run}/figures/convergence.png",
    log:
        "logs/{machine}/calibrate_{run}.log",
    benchmark:
        "logs/{machine}/calibrate_{run}.benchmark.tsv"
    priority: 3  # before the comparisons: the operating point every model variant is linearized at
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        machine_config=machine_config,
        settings=config["calibration"],
        source=log_source,
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: magnetic center from the calibration log (thesis ch. 3, 6.1)"
    script:
        "../workflow/scripts/calibrate.py"
