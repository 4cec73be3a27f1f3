# Stage "frf": empirical transfer function estimates (thesis eq. 4.1), SISO and MIMO, from the raw log.


rule frf:
    input:
        log="data/{machine}/{run}/identification.parquet",
    output:
        frf="results/{machine}/frf/{run}/frf.parquet",
        floor="results/{machine}/frf/{run}/floor.tsv",
        findings="results/{machine}/frf/{run}/findings.tsv",
        uff="results/{machine}/frf/{run}/frf.uff",
        radial_siso="results/{machine}/frf/{run}/figures/radial_siso.png",
        radial_mimo="results/{machine}/frf/{run}/figures/radial_mimo.png",
        axial="results/{machine}/frf/{run}/figures/axial.png",
    params:
        floor=config["frf"],
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    log:
        "logs/{machine}/frf_{run}.log",
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    script:
        "../workflow/scripts/frf.py"


rule import_thesis_m:
    # a user's thesis-style .m log, parsed by a strict grammar (never evaluated) into the Parquet log
    input:
        mfile="data/{machine}/{run}/identification.m",
    output:
        log="data/{machine}/{run}/identification.parquet",
    wildcard_constraints:
        run="|".join(thesis_m_runs()) or "no_thesis_m_runs",
    log:
        "logs/{machine}/import_thesis_m_{run}.log",
    params:
        library=LIBRARY_DIGEST,
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    script:
        "../workflow/scripts/import_thesis_m.py"
