# Stage "frf": empirical transfer function estimates (thesis eq. 4.1), SISO and MIMO, from the raw log
# (or, for a run with format uff, a user's UFF58 FRFs when no raw log exists).


rule plausibility:
    # the log against the nominal model, before the FRF (ambid.plausibility.check_units): frequencies, compliance and
    # coil currents within 30x of the model and of its sign, or one error naming the likely unit or channel; a
    # multisine run through its BLA, a run's UFF58 FRFs as they are (ambid.plausibility.frf_arrays)
    input:
        unpack(frf_input),
        machine=machine_model_file,
    output:
        table="results/{machine}/frf/{run}/plausibility.tsv",
    log:
        "logs/{machine}/plausibility_{run}.log",
    benchmark:
        "logs/{machine}/plausibility_{run}.benchmark.tsv"
    priority: 3  # before the comparisons: the measurement chain the model variants wait for
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        machine_config=machine_config,
        source=log_source,
        method=run_method,
        uff_options=uff_options,
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: the log against the nominal model (frequency, position and current units, signs)"
    script:
        "../workflow/scripts/plausibility.py"


rule frf:
    # an FRF only of a log that passed the check against the model (so a model change re-runs both; the FRF's bytes
    # do not change), then the log's model-free checks (ambid.plausibility.check_log: radial runs, outlier cells).
    # Not ancient(): Snakemake then skips the FRF's own reasons to re-run (a changed frf section) while the check re-runs.
    input:
        unpack(frf_input),
        plausibility="results/{machine}/frf/{run}/plausibility.tsv",
    output:
        frf="results/{machine}/frf/{run}/frf.parquet",
        floor="results/{machine}/frf/{run}/floor.tsv",
        findings="results/{machine}/frf/{run}/findings.tsv",
        uff="results/{machine}/frf/{run}/frf.uff",
        radial_siso="results/{machine}/frf/{run}/figures/radial_siso.png",
        radial_mimo="results/{machine}/frf/{run}/figures/radial_mimo.png",
        axial="results/{machine}/frf/{run}/figures/axial.png",
    log:
        "logs/{machine}/frf_{run}.log",
    benchmark:
        "logs/{machine}/frf_{run}.benchmark.tsv"
    wildcard_constraints:
        run="|".join(run for _, run in identification_runs("stepped_sine")) or "no_stepped_sine_runs",
    priority: 3  # before the comparisons: the measurement chain the model variants wait for
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        settings=config["frf"],
        source=log_source,
        dpi=config["figures"]["dpi"],
        uff_options=uff_options,
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: SISO, MIMO and coil-current FRFs (thesis eq. 4.1) and their floor"
    script:
        "../workflow/scripts/frf.py"


rule bla:
    # a multisine run: best linear approximation with its noise and nonlinear distortion (Pintelon & Schoukens)
    input:
        log="data/{machine}/{run}/multisine.parquet",
        plausibility="results/{machine}/frf/{run}/plausibility.tsv",
    output:
        frf="results/{machine}/frf/{run}/frf.parquet",
        uff="results/{machine}/frf/{run}/frf.uff",
        distortion="results/{machine}/frf/{run}/distortion.tsv",
        radial_mimo="results/{machine}/frf/{run}/figures/radial_mimo.png",
        axial="results/{machine}/frf/{run}/figures/axial.png",
        distortion_figure="results/{machine}/frf/{run}/figures/distortion.png",
    log:
        "logs/{machine}/bla_{run}.log",
    benchmark:
        "logs/{machine}/bla_{run}.benchmark.tsv"
    wildcard_constraints:
        run="|".join(run for _, run in identification_runs("multisine")) or "no_multisine_runs",
    priority: 3  # before the comparisons: the measurement chain the model variants wait for
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,  # minutes (cluster executors)
    params:
        dpi=config["figures"]["dpi"],
        settings=config["frf"],
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: best linear approximation of the multisine run, its noise and distortion"
    script:
        "../workflow/scripts/bla.py"


rule identification_methods:
    # the machine's identification runs side by side: machine time, noise and systematic floors (report section)
    input:
        frf=lambda wildcards: [
            f"results/{wildcards.machine}/frf/{run}/frf.parquet" for run in runs_of_machine(wildcards.machine)
        ],
        logs=lambda wildcards: [
            identification_log(wildcards.machine, run) for run in runs_of_machine(wildcards.machine)
        ],
    output:
        table="results/{machine}/methods/comparison.tsv",
        figure="results/{machine}/methods/figures/methods.png",
    log:
        "logs/{machine}/identification_methods.log",
    benchmark:
        "logs/{machine}/identification_methods.benchmark.tsv"
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,  # minutes (cluster executors)
    params:
        runs=lambda wildcards: runs_of_machine(wildcards.machine),
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine}: the identification runs side by side (machine time, noise and systematic floors)"
    script:
        "../workflow/scripts/identification_methods.py"


rule import_log:
    input:
        raw=user_log_file,
    output:
        log="data/{machine}/{run}/identification.parquet",
    log:
        "logs/{machine}/import_log_{run}.log",
    benchmark:
        "logs/{machine}/import_log_{run}.benchmark.tsv"
    wildcard_constraints:
        run="|".join(imported_runs()) or "no_imported_runs",
    priority: 3  # before the comparisons: the measurement chain the model variants wait for
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        format=lambda wildcards: RUNS[(wildcards.machine, wildcards.run)]["format"],
        units=reader_units,
        source=log_source,
        library=LIBRARY_DIGEST,
    # a user's log (thesis-style .m, plain CSV / Parquet table, MATLAB .mat), converted once into the canonical
    # Parquet log (ambid.readers); a .m file is parsed by a strict grammar, never evaluated
    message:
        "{wildcards.machine} {wildcards.run}: {input.raw} converted into the canonical log"
    script:
        "../workflow/scripts/import_log.py"
