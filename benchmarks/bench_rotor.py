"""Speed benchmark of the rotor model and the plant FRF, on one core, optionally against ROSS.

Run from the repository root::

    python benchmarks/bench_rotor.py            # figures table
    python benchmarks/bench_rotor.py --profile  # plus cProfile of ambid's two timed calls

Measured (demo20 machine, ``config/machines/demo20.yaml``):

1. FEM assembly + modal analysis per second: each repetition builds a fresh
   ``Rotor`` from the demo20 rotor's elements, disks and sleeves (cold caches)
   and calls ``planar_modes(machine.retained_modes)``.  Target >= 1000 /s.
2. The 4x4 radial plant FRF on 250 frequencies (1 .. 1000 Hz) with the
   ``Plant`` built once (only the FRF call is timed).  Target <= 10 ms.  Also
   shown: building the Plant from a cold rotor plus the FRF.
3. If ROSS is importable, the same rotor in ROSS (Timoshenko elements, no
   disks) with two linear bearings at the nodes nearest to the AMB actuators,
   stiffness ``kxx = kyy = +kx`` (the magnitude of the AMB negative stiffness;
   a negative value would make the ROSS rotor unstable, and the bearing
   stiffness does not change the cost):

   * ``run_modal(speed=0, num_modes=2 * retained_modes, sparse=False)``: the
     dense solver (``scipy.linalg.eig`` of the 2 x 6-DOF-per-node state
     matrix plus ROSS' mode-shape post-processing), timed on a prebuilt rotor
     with its result cache cleared, and with the rotor build included;
   * ``run_freq_response(speed_range=2 pi f, free_free=True)`` over the same
     250 frequencies: speed 0 and excitation frequency swept, like ambid's
     non-rotating plant.  ROSS returns the full receptance matrix of all DOFs
     (plus velocity and acceleration), ambid the 4x4 current-to-position plant
     of a 12-mode model, so the figures compare the cost of each code's route
     to an FRF, not identical outputs.

   Target: ambid >= 20x faster than ROSS for both.

Each figure is the median over several batches timed with ``time.perf_counter``;
BLAS/OpenMP are limited to one thread before numpy is imported.  The exit code
is always 0: this is a benchmark, not a test.
"""

import os

for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_variable] = "1"

import argparse  # noqa: E402
import contextlib  # noqa: E402
import cProfile  # noqa: E402
import dataclasses  # noqa: E402
import platform  # noqa: E402
import pstats  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
try:
    import ambid  # noqa: F401
except ModuleNotFoundError:  # not installed: use the source tree
    sys.path.insert(0, str(REPO / "workflow"))

from ambid.machine import machine_from_config  # noqa: E402
from ambid.plant import Plant  # noqa: E402
from ambid.ross_export import to_ross_rotor  # noqa: E402
from ambid.rotor import Rotor  # noqa: E402

CONFIG = REPO / "config" / "machines" / "demo20.yaml"
FREQUENCY_HZ = np.linspace(1.0, 1000.0, 250)
MODAL_TARGET_PER_S = 1000.0
FRF_TARGET_S = 10e-3
ROSS_SPEEDUP_TARGET = 20.0


# ------------------------------------------------------------------- timing
def median_time_s(function, batches=7, min_batch_s=0.2, max_calls=100000):
    """Median time per call [s] of ``function()`` over ``batches`` batches.

    The batch size is calibrated so that one batch lasts about ``min_batch_s``
    (at least one call); one warm-up call precedes the measurement.
    """
    function()
    calls = 1
    while True:
        start = time.perf_counter()
        for _ in range(calls):
            function()
        elapsed = time.perf_counter() - start
        if elapsed >= min_batch_s or calls >= max_calls:
            break
        calls = min(max_calls, max(2 * calls, int(calls * 1.2 * min_batch_s / max(elapsed, 1e-9))))
    per_call = [elapsed / calls]
    for _ in range(batches - 1):
        start = time.perf_counter()
        for _ in range(calls):
            function()
        per_call.append((time.perf_counter() - start) / calls)
    return statistics.median(per_call)


@contextlib.contextmanager
def silenced_output():
    """Send the process' stdout and stderr (file descriptors 1, 2) to /dev/null.

    ROSS' import chain prints REFPROP diagnostics from Python and C code.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


def import_ross():
    """The ross module, or None and the reason it is unavailable."""
    try:
        with silenced_output():
            import ross
    except ImportError as error:
        return None, f"{type(error).__name__}: {error}"
    return ross, ""


# ------------------------------------------------------------------ models
def load_machine():
    with open(CONFIG) as stream:
        return machine_from_config(yaml.safe_load(stream))


def fresh_rotor(rotor):
    """A new Rotor with the same parts and empty caches."""
    return Rotor(elements=rotor.elements, disks=rotor.disks, sleeves=rotor.sleeves)


def ross_rotor(machine, bearing_stiffness_n_m):
    """The machine's rotor in ROSS with linear bearings at the nodes nearest to the actuators."""
    nodes_z_m = machine.rotor.node_positions_m
    nodes = [int(np.argmin(np.abs(nodes_z_m - b.actuator_position_m))) for b in machine.radial_bearings]
    return to_ross_rotor(machine.rotor, [(node, bearing_stiffness_n_m) for node in nodes])


# --------------------------------------------------------------- benchmark
def run(profile=False):
    machine = load_machine()
    rotor = machine.rotor
    rows = []  # (quantity, value text, target text, verdict)

    def modal():
        fresh_rotor(rotor).planar_modes(machine.retained_modes)

    modal_s = median_time_s(modal)
    rows.append(
        (
            "ambid: assembly + modal analysis (demo20)",
            f"{1 / modal_s:10.0f} /s  ({modal_s * 1e3:.3f} ms)",
            f">= {MODAL_TARGET_PER_S:.0f} /s",
            "PASS" if 1 / modal_s >= MODAL_TARGET_PER_S else "FAIL",
        )
    )

    plant = Plant(machine)

    def frf():
        plant.radial_frequency_response(FREQUENCY_HZ)

    frf_s = median_time_s(frf)
    rows.append(
        (
            "ambid: 4x4 plant FRF, 250 frequencies",
            f"{frf_s * 1e3:10.3f} ms",
            f"<= {FRF_TARGET_S * 1e3:.0f} ms",
            "PASS" if frf_s <= FRF_TARGET_S else "FAIL",
        )
    )

    def cold_plant_frf():
        Plant(dataclasses.replace(machine, rotor=fresh_rotor(rotor))).radial_frequency_response(FREQUENCY_HZ)

    cold_s = median_time_s(cold_plant_frf)
    rows.append(("ambid: Plant(machine) cold + FRF", f"{cold_s * 1e3:10.3f} ms", "-", "info"))

    rs, reason = import_ross()
    ross_note = ""
    if rs is not None:
        stiffness_n_m = float(np.max(np.abs(plant.position_stiffness)))
        ross_note = (
            f"ROSS {rs.__version__}: demo20 rotor, {rotor.n_elements} Timoshenko elements, 6 DOF/node "
            f"({6 * rotor.n_nodes} DOF), bearings kxx = kyy = {stiffness_n_m:.4g} N/m (= |kx|) at the nodes "
            "nearest to the actuators"
        )
        num_modes = 2 * machine.retained_modes
        with silenced_output():  # first calls compile ROSS' numba code and may warn
            prebuilt = ross_rotor(machine, stiffness_n_m)

            def ross_modal():
                prebuilt.run_modal.cache_clear()
                prebuilt.run_modal(speed=0.0, num_modes=num_modes, sparse=False)

            def ross_build_modal():
                ross_rotor(machine, stiffness_n_m).run_modal(speed=0.0, num_modes=num_modes, sparse=False)

            speed_range_rad_s = 2 * np.pi * FREQUENCY_HZ

            def ross_frf():
                prebuilt._run_freq_response.cache_clear()
                prebuilt.run_freq_response(speed_range=speed_range_rad_s, free_free=True)

            ross_modal_s = median_time_s(ross_modal, batches=5)
            ross_build_modal_s = median_time_s(ross_build_modal, batches=5)
            ross_frf_s = median_time_s(ross_frf, batches=3, min_batch_s=0.0)
        rows += [
            (f"ROSS: run_modal dense, num_modes={num_modes}", f"{ross_modal_s * 1e3:10.3f} ms", "-", "info"),
            ("ROSS: Rotor build + run_modal dense", f"{ross_build_modal_s * 1e3:10.3f} ms", "-", "info"),
            ("ROSS: run_freq_response, 250 frequencies", f"{ross_frf_s * 1e3:10.3f} ms", "-", "info"),
        ]
        for label, ratio in (
            ("speed-up modal: ROSS run_modal / ambid assembly+modal", ross_modal_s / modal_s),
            ("speed-up modal: ROSS build+run_modal / ambid assembly+modal", ross_build_modal_s / modal_s),
            ("speed-up FRF: ROSS run_freq_response / ambid FRF", ross_frf_s / frf_s),
            ("speed-up FRF: ROSS run_freq_response / ambid cold Plant+FRF", ross_frf_s / cold_s),
        ):
            verdict = "PASS" if ratio >= ROSS_SPEEDUP_TARGET else "FAIL"
            rows.append((label, f"{ratio:10.1f} x", f">= {ROSS_SPEEDUP_TARGET:.0f} x", verdict))
    else:
        ross_note = f"ROSS not available ({reason}); ambid figures only"

    print("ambid rotor benchmark (one core)")
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}, "
        f"{os.cpu_count()} CPUs visible, OMP/OPENBLAS/MKL_NUM_THREADS=1"
    )
    print(
        f"machine demo20: {rotor.n_elements} elements, {rotor.n_nodes} nodes, "
        f"{machine.retained_modes} retained planar modes; FRF grid 1 .. 1000 Hz, {FREQUENCY_HZ.size} points"
    )
    print(ross_note)
    print()
    header = ("quantity", "value", "target", "result")
    widths = [max(len(row[k]) for row in rows + [header]) for k in range(4)]
    line = "  ".join("-" * w for w in widths)
    print("  ".join(h.ljust(w) for h, w in zip(header, widths)))
    print(line)
    for row in rows:
        print("  ".join(text.ljust(w) for text, w in zip(row, widths)))

    if profile:
        for label, function, repetitions in (("assembly + modal", modal, 2000), ("plant FRF", frf, 200)):
            profiler = cProfile.Profile()
            profiler.enable()
            for _ in range(repetitions):
                function()
            profiler.disable()
            print(f"\ncProfile of ambid {label} ({repetitions} calls), top 12 by internal time:")
            pstats.Stats(profiler, stream=sys.stdout).sort_stats("tottime").print_stats(12)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", action="store_true", help="also print a cProfile of ambid's timed calls")
    args = parser.parse_args(argv)
    try:
        run(profile=args.profile)
    except Exception as error:  # a benchmark reports, it does not fail the build
        print(f"benchmark error: {type(error).__name__}: {error}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
