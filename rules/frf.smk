# Stage "frf": empirical transfer function estimates (thesis eq. 4.1), SISO and MIMO, from the raw log.


rule frf:
    input:
        log="data/{machine}/{run}/identification.parquet",
    wildcard_constraints:
        run="|".join(run for _, run in identification_runs("stepped_sine")) or "no_stepped_sine_runs",
    output:
        frf="results/{machine}/frf/{run}/frf.parquet",
        uff="results/{machine}/frf/{run}/frf.uff",
        radial_siso="results/{machine}/frf/{run}/figures/radial_siso.png",
        radial_mimo="results/{machine}/frf/{run}/figures/radial_mimo.png",
        axial="results/{machine}/frf/{run}/figures/axial.png",
    params:
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


rule bla:
    # a multisine run: best linear approximation with its noise and nonlinear distortion (Pintelon & Schoukens)
    input:
        log="data/{machine}/{run}/multisine.parquet",
    wildcard_constraints:
        run="|".join(run for _, run in identification_runs("multisine")) or "no_multisine_runs",
    output:
        frf="results/{machine}/frf/{run}/frf.parquet",
        uff="results/{machine}/frf/{run}/frf.uff",
        distortion="results/{machine}/frf/{run}/distortion.tsv",
        radial_mimo="results/{machine}/frf/{run}/figures/radial_mimo.png",
        axial="results/{machine}/frf/{run}/figures/axial.png",
        distortion_figure="results/{machine}/frf/{run}/figures/distortion.png",
    params:
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    log:
        "logs/{machine}/bla_{run}.log",
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,  # minutes (cluster executors)
    script:
        "../workflow/scripts/bla.py"


rule identification_methods:
    # the machine's identification runs side by side: machine time, noise and systematic floors (report section)
    input:
        frf=lambda wildcards: [f"results/{wildcards.machine}/frf/{run}/frf.parquet" for run in runs_of_machine(wildcards.machine)],
        logs=lambda wildcards: [identification_log(wildcards.machine, run) for run in runs_of_machine(wildcards.machine)],
    output:
        table="results/{machine}/methods/comparison.tsv",
        figure="results/{machine}/methods/figures/methods.png",
    params:
        runs=lambda wildcards: runs_of_machine(wildcards.machine),
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    log:
        "logs/{machine}/identification_methods.log",
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,  # minutes (cluster executors)
    script:
        "../workflow/scripts/identification_methods.py"


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
