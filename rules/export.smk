# Stage "export": the FRFs and fitted models of a run as CSV and MATLAB .mat files (the UFF58 file is the frf stage's).


rule export:
    input:
        frf="results/{machine}/frf/{run}/frf.parquet",
        models="results/{machine}/fit/{run}/models.parquet",
    output:
        frf_csv="results/{machine}/export/{run}/frf.csv",
        frf_mat="results/{machine}/export/{run}/frf.mat",
        models_csv="results/{machine}/export/{run}/models.csv",
        models_mat="results/{machine}/export/{run}/models.mat",
    log:
        "logs/{machine}/export_{run}.log",
    benchmark:
        "logs/{machine}/export_{run}.benchmark.tsv"
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: FRFs and fitted models as CSV and .mat"
    script:
        "../workflow/scripts/export.py"
