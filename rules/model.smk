# Stage "model": the nominal model of each machine (mode table, plant FRF, stability, figures).


rule model:
    input:
        machine=machine_model_file,
    output:
        modes="results/{machine}/model/{variant}/modes.tsv",
        frf="results/{machine}/model/{variant}/plant_frf.parquet",
        stability="results/{machine}/model/{variant}/stability.tsv",
        bode=report(
            "results/{machine}/model/{variant}/figures/plant_bode.png",
            caption="../workflow/report/plant_bode.rst",
            category="Model",
            subcategory="{machine}",
        ),
        axial_bode=report(
            "results/{machine}/model/{variant}/figures/axial_bode.png",
            caption="../workflow/report/plant_bode.rst",
            category="Model",
            subcategory="{machine}",
        ),
        mode_shapes=report(
            "results/{machine}/model/{variant}/figures/mode_shapes.png",
            caption="../workflow/report/mode_shapes.rst",
            category="Model",
            subcategory="{machine}",
        ),
    params:
        machine_config=machine_config,
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    log:
        "logs/{machine}/model_{variant}.log",
    benchmark:
        "logs/{machine}/model_{variant}.benchmark.tsv"
    threads: 1
    resources:
        mem_mb=1000,
    script:
        "../workflow/scripts/model.py"
