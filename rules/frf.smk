# Stage "frf": empirical transfer function estimates (thesis eq. 4.1), SISO and MIMO, from the raw log.


rule frf:
    input:
        log="data/{machine}/{run}/identification.parquet",
    output:
        frf="results/{machine}/frf/{run}/frf.parquet",
        uff="results/{machine}/frf/{run}/frf.uff",
        radial_siso=report(
            "results/{machine}/frf/{run}/figures/radial_siso.png",
            caption="../workflow/report/frf.rst",
            category="FRF",
            subcategory="{machine}",
        ),
        radial_mimo=report(
            "results/{machine}/frf/{run}/figures/radial_mimo.png",
            caption="../workflow/report/frf.rst",
            category="FRF",
            subcategory="{machine}",
        ),
        axial=report(
            "results/{machine}/frf/{run}/figures/axial.png",
            caption="../workflow/report/frf.rst",
            category="FRF",
            subcategory="{machine}",
        ),
    params:
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    log:
        "logs/{machine}/frf_{run}.log",
    threads: 1
    script:
        "../workflow/scripts/frf.py"
