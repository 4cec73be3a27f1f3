# Stage "fit": parametric models of the FRFs, resonances and anti-resonances (thesis ch. 5.1).


rule fit:
    input:
        frf="results/{machine}/frf/{run}/frf.parquet",
        machine=machine_model_file,
    output:
        features="results/{machine}/fit/{run}/features.parquet",
        table="results/{machine}/fit/{run}/features.tsv",
        models="results/{machine}/fit/{run}/models.parquet",
        bode=report(
            "results/{machine}/fit/{run}/figures/bode_fit.png",
            caption="../workflow/report/fit_bode.rst",
            category="Fit",
            subcategory="{machine}",
        ),
        stabilization=report(
            "results/{machine}/fit/{run}/figures/stabilization.png",
            caption="../workflow/report/fit_stabilization.rst",
            category="Fit",
            subcategory="{machine}",
        ),
    params:
        machine_config=machine_config,
        settings=config["fit"],
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    log:
        "logs/{machine}/fit_{run}.log",
    benchmark:
        "logs/{machine}/fit_{run}.benchmark.tsv"
    threads: 1
    script:
        "../workflow/scripts/fit.py"
