# Stage "model": each model variant of a machine (its machine config, mode table, plant FRF, stability, figures).


rule variant:
    input:
        unpack(variant_inputs),
    output:
        machine="results/{machine}/model/{variant}/machine.yaml",
    log:
        "logs/{machine}/variant_{variant}.log",
    benchmark:
        "logs/{machine}/variant_{variant}.benchmark.tsv"
    priority: 3  # before the comparisons: the machine file the diagnoses wait for
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        machine_config=machine_config,
        steps=variant_steps,
        library=LIBRARY_DIGEST,
    # a variant's machine config: the machine file, the calibrated operating point, added effects, updates
    message:
        "{wildcards.machine}: machine file of model variant {wildcards.variant}"
    script:
        "../workflow/scripts/variant.py"


rule model:
    input:
        machine="results/{machine}/model/{variant}/machine.yaml",
    output:
        modes="results/{machine}/model/{variant}/modes.tsv",
        frf="results/{machine}/model/{variant}/plant_frf.parquet",
        stability="results/{machine}/model/{variant}/stability.tsv",
        bode="results/{machine}/model/{variant}/figures/plant_bode.png",
        axial_bode="results/{machine}/model/{variant}/figures/axial_bode.png",
        mode_shapes="results/{machine}/model/{variant}/figures/mode_shapes.png",
    log:
        "logs/{machine}/model_{variant}.log",
    benchmark:
        "logs/{machine}/model_{variant}.benchmark.tsv"
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine}: modes, plant FRF and stability of model variant {wildcards.variant}"
    script:
        "../workflow/scripts/model.py"
