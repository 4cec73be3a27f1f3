# Stage "frf": empirical transfer function estimates (thesis eq. 4.1), SISO and MIMO, from the raw log.


rule frf:
    # the log is checked against the nominal model first (ambid.plausibility): axes, units, outlier steps
    input:
        log="data/{machine}/{run}/identification.parquet",
        machine=machine_model_file,
    output:
        frf="results/{machine}/frf/{run}/frf.parquet",
        findings="results/{machine}/frf/{run}/findings.tsv",
        uff="results/{machine}/frf/{run}/frf.uff",
        radial_siso="results/{machine}/frf/{run}/figures/radial_siso.png",
        radial_mimo="results/{machine}/frf/{run}/figures/radial_mimo.png",
        axial="results/{machine}/frf/{run}/figures/axial.png",
    params:
        machine_config=machine_config,
        settings=config["frf"],
        source=log_source,
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
        source=log_source,
        library=LIBRARY_DIGEST,
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    script:
        "../workflow/scripts/import_thesis_m.py"
