# Stage "commissioning": per stepped-sine identification run, the measured sensitivity |U2/Eu| of each axis with its
# ISO 14839-3 zone and margins beside the models' (nominal and the last variant), and the Campbell diagram.


rule commissioning:
    input:
        log="data/{machine}/{run}/identification.parquet",
        models=lambda wildcards: [
            f"results/{wildcards.machine}/model/{variant}/machine.yaml"
            for variant in commissioning_variants(wildcards.machine)
        ],
        features="results/{machine}/fit/{run}/features.tsv",
    output:
        sensitivity="results/{machine}/commissioning/{run}/sensitivity.tsv",
        campbell="results/{machine}/commissioning/{run}/campbell.tsv",
        sensitivity_figure="results/{machine}/commissioning/{run}/figures/sensitivity.png",
        campbell_figure="results/{machine}/commissioning/{run}/figures/campbell.png",
        modes_figure="results/{machine}/commissioning/{run}/figures/levitated_modes.png",
    log:
        "logs/{machine}/commissioning_{run}.log",
    benchmark:
        "logs/{machine}/commissioning_{run}.benchmark.tsv"
    conda:
        "../workflow/envs/ambid.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,  # minutes (cluster executors)
    params:
        variants=lambda wildcards: commissioning_variants(wildcards.machine),
        settings=lambda wildcards: {
            "campbell_speed_rpm": config["figures"]["campbell_speed_rpm"],
            "campbell_speeds": config["figures"]["campbell_speeds"],
        },
        dpi=config["figures"]["dpi"],
        library=LIBRARY_DIGEST,
    message:
        "{wildcards.machine} {wildcards.run}: measured sensitivity, ISO 14839-3 zones, margins, Campbell diagram"
    script:
        "../workflow/scripts/commissioning.py"
