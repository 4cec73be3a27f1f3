# Stage "acquire": measurement runs against the virtual rig (the only rules that read its truth).  The runs are
# planned with the rig's as-built machine file, as a test engineer plans with the drawing: editing the model
# (config/machines/) re-runs no acquisition.
# A user with a real machine skips these: runs with source "data" expect their logs in data/.


rule acquire_identification:
    input:
        unpack(identification_center),
        unpack(rig_files),
    output:
        log="data/{machine}/{run}/identification.parquet",
        mfile="data/{machine}/{run}/identification.m",
    log:
        "logs/{machine}/acquire_identification_{run}.log",
    benchmark:
        "logs/{machine}/acquire_identification_{run}.benchmark.tsv"
    wildcard_constraints:
        run="|".join(run for _, run in runs_of("identification", "rig")) or "no_rig_runs",
    priority: 4  # first: the head of the longest chain (measurement -> FRF -> fit -> update -> variants)
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,  # minutes (cluster executors)
    params:
        as_built_config=as_built_config,
        rig_config=rig_config,
        settings=config["identification"],
        calibration=config["calibration"],
        seed=run_seed,
        library=LIBRARY_DIGEST,
    # centred on the magnetic center its calibration run found (thesis ch. 6), when the run names one
    message:
        "{wildcards.machine} {wildcards.run}: stepped-sine identification on the virtual rig (thesis ch. 4.2)"
    script:
        "../workflow/scripts/acquire_identification.py"


rule acquire_multisine:
    # random-phase multisines (coarse pass, its fit, a zoom pass around what the fit found), centred as above
    input:
        unpack(identification_center),
        unpack(rig_files),
    output:
        log="data/{machine}/{run}/multisine.parquet",
    log:
        "logs/{machine}/acquire_multisine_{run}.log",
    benchmark:
        "logs/{machine}/acquire_multisine_{run}.benchmark.tsv"
    wildcard_constraints:
        run="|".join(run for _, run in identification_runs("multisine", "rig")) or "no_rig_runs",
    priority: 4  # first: the head of the longest chain (measurement -> FRF -> fit -> update -> variants)
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,  # minutes (cluster executors)
    params:
        as_built_config=as_built_config,
        rig_config=rig_config,
        settings=config["multisine"],
        fit=config["fit"],
        calibration=config["calibration"],
        seed=run_seed,
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: multisine identification on the virtual rig (coarse pass, fit, zoom)"
    script:
        "../workflow/scripts/acquire_multisine.py"


rule acquire_calibration:
    input:
        unpack(rig_files),
    output:
        log="data/{machine}/{run}/calibration.parquet",
    log:
        "logs/{machine}/acquire_calibration_{run}.log",
    benchmark:
        "logs/{machine}/acquire_calibration_{run}.benchmark.tsv"
    wildcard_constraints:
        run="|".join(run for _, run in runs_of("calibration", "rig")) or "no_rig_runs",
    priority: 4  # first: the head of the longest chain (measurement -> FRF -> fit -> update -> variants)
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        as_built_config=as_built_config,
        rig_config=rig_config,
        settings=config["calibration"],
        seed=run_seed,
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: magnetic center calibration on the virtual rig (thesis ch. 3.3)"
    script:
        "../workflow/scripts/acquire_calibration.py"


rule calibration_sensitivity:
    input:
        unpack(rig_files),
        machine=machine_model_file,
    output:
        table="results/{machine}/calibration/{run}/sensitivity.tsv",
    log:
        "logs/{machine}/calibration_sensitivity_{run}.log",
    benchmark:
        "logs/{machine}/calibration_sensitivity_{run}.benchmark.tsv"
    priority: 1  # a long job that feeds only the report: not one left for the end
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        machine_config=machine_config,
        as_built_config=as_built_config,
        rig_config=rig_config,
        settings=config["calibration"],
        seed=run_seed,
        library=LIBRARY_DIGEST,
    # a virtual experiment: the method run with wrong g0, b, theta or a current-sensor offset,
    # scored against the rig's truth (which is why it lives with the rig rules)
    message:
        "{wildcards.machine} {wildcards.run}: sensitivity of the magnetic center to parameter errors (rig)"
    script:
        "../workflow/scripts/calibration_sensitivity.py"
