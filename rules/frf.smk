# Stage "frf": empirical transfer function estimates (thesis eq. 4.1), SISO and MIMO, from the raw log.


rule plausibility:
    # the log against the nominal model, before the FRF (ambid.plausibility.check_units): frequencies, compliance and
    # coil currents within 30x of the model, or one error naming the likely unit
    input:
        log="data/{machine}/{run}/identification.parquet",
        machine=machine_model_file,
    output:
        table="results/{machine}/frf/{run}/plausibility.tsv",
    params:
        machine_config=machine_config,
        source=log_source,
        library=LIBRARY_DIGEST,
    log:
        "logs/{machine}/plausibility_{run}.log",
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    script:
        "../workflow/scripts/plausibility.py"


rule frf:
    # an FRF only of a log that passed the check against the model (so a model change re-runs both; the FRF's bytes
    # do not change), then the log's model-free checks (ambid.plausibility.check_log: radial runs, outlier cells).
    # Not ancient(): Snakemake then skips the FRF's own reasons to re-run (a changed frf section) while the check re-runs.
    input:
        log="data/{machine}/{run}/identification.parquet",
        plausibility="results/{machine}/frf/{run}/plausibility.tsv",
    output:
        frf="results/{machine}/frf/{run}/frf.parquet",
        findings="results/{machine}/frf/{run}/findings.tsv",
        uff="results/{machine}/frf/{run}/frf.uff",
        radial_siso="results/{machine}/frf/{run}/figures/radial_siso.png",
        radial_mimo="results/{machine}/frf/{run}/figures/radial_mimo.png",
        axial="results/{machine}/frf/{run}/figures/axial.png",
    params:
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
