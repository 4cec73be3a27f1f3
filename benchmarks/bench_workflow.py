"""Workflow wall times: end to end, a second run, one model change, and N machines x runs against --cores.

Part 1 (the issue-8 targets): the default configuration from clean with --cores 2 (target <= 180 s),
the same again (target: no job), then one model parameter of hs_eden_like changed (only the rules
downstream of the machine file re-run; acquisition and FRF do not).
Part 2 (scale): N copies of demo20, each measured on its rig in one calibration and R identification
runs, the whole workflow from clean with --cores 1 and --cores 2; the ratio is the parallel speed-up.

Usage: ``.venv/bin/python benchmarks/bench_workflow.py [N] [R]`` (defaults 2 2).  Run on an idle machine:
every figure is wall time.  Copies of config/ and the shipped example log go to a temporary folder.

``bench_workflow.py --against REV [K]`` runs instead the default configuration from clean with --cores 2, K times
(default 2) with this tree and K times with the commit REV (exported with ``git archive``, its own library on the
path), alternating ABBA, and prints their medians and ratio.  The same commit's figure moved by 15 % within an hour on
the 2-core machine of stop 40 (127.6 s, then 148.1 s): a change's effect is the ratio, not one run's wall time.
"""

import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE_LOG = "data/demo20/thesis01/identification.m"


def snakemake(workdir, *args, root=ROOT):
    """Run the workflow of the tree ``root`` (its Snakefile and library) in ``workdir``: (wall s, output)."""
    started = time.perf_counter()
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root / "workflow"), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, "-m", "snakemake", "-s", str(root / "Snakefile"), "-d", str(workdir), *args],
                            capture_output=True, text=True, env=environment)
    if result.returncode != 0:
        raise SystemExit(result.stderr[-3000:])
    return time.perf_counter() - started, result.stdout + result.stderr


def jobs(output):
    """Rule -> jobs run, from Snakemake's 'Job stats' table (empty when nothing was to be done)."""
    if "Job stats:" not in output:
        return {}
    table = output.split("Job stats:", 1)[1].split("total", 1)[0]
    return {rule: int(count) for rule, count in re.findall(r"^(\w+)\s+(\d+)\s*$", table, re.M)}


def working_directory(parent, name, root=ROOT):
    workdir = parent / name
    shutil.copytree(root / "config", workdir / "config")
    (workdir / EXAMPLE_LOG).parent.mkdir(parents=True)
    shutil.copy(root / EXAMPLE_LOG, workdir / EXAMPLE_LOG)
    return workdir


def tree_at(revision, parent):
    """The repository at ``revision`` (``git archive``), its library compiled as `make run` compiles it."""
    tree = parent / f"tree_{revision}"
    tree.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", revision], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "workflow" / "ambid")], check=True)
    return tree


def part_against(parent, revision, rounds):
    trees = {revision: tree_at(revision, parent), "this tree": ROOT}
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(ROOT / "workflow" / "ambid")], check=True)
    walls = {label: [] for label in trees}
    for r in range(rounds):
        for label in (list(trees) if r % 2 == 0 else list(trees)[::-1]):  # ABBA: a drift of the machine cancels
            workdir = working_directory(parent, f"against_{r}_{len(walls[label])}_{label.replace(' ', '_')}", trees[label])
            wall, output = snakemake(workdir, "--cores", "2", root=trees[label])
            walls[label].append(wall)
            print(f"round {r + 1}, {label:10s}: {wall:6.1f} s wall, {sum(jobs(output).values())} jobs", flush=True)
    base, this = (statistics.median(walls[label]) for label in trees)
    print(f"median {revision}: {base:6.1f} s, this tree: {this:6.1f} s; ratio this / {revision}: {this / base:.3f} "
          f"(target: the default run <= 120 s on 2 cores)")


def part_default(parent):
    workdir = working_directory(parent, "default")
    wall, output = snakemake(workdir, "--cores", "2")
    print(f"default configuration from clean, --cores 2: {wall:6.1f} s wall, {sum(jobs(output).values())} jobs "
          f"(target <= 180 s)")
    wall, output = snakemake(workdir, "--cores", "2")
    print(f"second run:                                 {wall:6.1f} s wall, {sum(jobs(output).values())} jobs (target 0)")
    path = workdir / "config/machines/hs_eden_like.yaml"
    machine = yaml.safe_load(path.read_text())
    machine["materials"]["steel"]["youngs_modulus_pa"] *= 0.98
    path.write_text(yaml.safe_dump(machine))
    wall, output = snakemake(workdir, "--cores", "2")
    rerun = jobs(output)
    print(f"hs_eden_like steel modulus -2 %:            {wall:6.1f} s wall, {sum(rerun.values())} jobs: "
          + ", ".join(f"{rule} {n}" for rule, n in sorted(rerun.items())))
    untouched = {"acquire_calibration", "acquire_identification", "frf", "import_log"} & set(rerun)
    print(f"  acquisition / FRF re-run: {sorted(untouched) or 'none'}")


def scaled_configuration(workdir, machines, runs):
    """N copies of demo20 on their rigs, each with one calibration and ``runs`` identification runs."""
    config = yaml.safe_load((workdir / "config/config.yaml").read_text())
    template, entries = config["machines"]["demo20"], {}
    rig = yaml.safe_load((workdir / "config/rigs/demo20.yaml").read_text())
    for m in range(machines):
        name = f"demo20_{m}"
        rig_path = workdir / f"config/rigs/{name}.yaml"
        rig_path.write_text(yaml.safe_dump({**rig, "machine": name, "name": f"{name}_rig"}))
        identification = {f"ident{r:02d}": {"kind": "identification", "source": "rig", "seed": 10 * m + r,
                                            "calibration": "cal01"} for r in range(runs)}
        entries[name] = {**template, "rig": f"config/rigs/{name}.yaml", "operating_point": "cal01",
                         "runs": {"cal01": {"kind": "calibration", "source": "rig", "seed": m}, **identification},
                         "variants": {"updated": {"update": "ident00"}}}
    config["machines"] = entries
    config["calibration"].update(repetitions=2, average_s=0.3)
    config["diagnose"]["sequence_length"] = 1
    (workdir / "config/config.yaml").write_text(yaml.safe_dump(config))


def part_scale(parent, machines, runs):
    walls = {}
    for cores in (1, 2):
        workdir = working_directory(parent, f"scale_{cores}")
        scaled_configuration(workdir, machines, runs)
        walls[cores], output = snakemake(workdir, "--cores", str(cores))
        print(f"{machines} machines x ({runs} identification + 1 calibration) runs, --cores {cores}: "
              f"{walls[cores]:6.1f} s wall, {sum(jobs(output).values())} jobs")
    print(f"  speed-up --cores 2 / --cores 1: {walls[1] / walls[2]:.2f} (ideal 2)")


def main():
    if sys.argv[1:2] == ["--against"]:
        with tempfile.TemporaryDirectory() as parent:
            part_against(Path(parent), sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else 2)
        return
    machines, runs = (int(a) for a in (sys.argv[1:3] + ["2", "2"][len(sys.argv[1:3]):]))
    with tempfile.TemporaryDirectory() as parent:
        part_default(Path(parent))
        part_scale(Path(parent), machines, runs)


if __name__ == "__main__":
    main()
