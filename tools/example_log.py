"""Write the shipped example log data/demo20/thesis01/identification.m (README "Real logs").

A stepped-sine identification of the demo20 virtual rig (the thesis' reference rotor, ch. 5.3),
made at the rig's magnetic center as after a calibration, on a thinned grid and written in the
thesis' .m layout with 8 significant digits: what a user of a real machine drops into data/.
The workflow then reads it with no rig (config.yaml: runs.thesis01 {source: data, format: m}).

Run from the repository root: ``.venv/bin/python tools/example_log.py``.  Same seed, same file.
"""

import copy
from pathlib import Path

import yaml

from ambid.excitation import StepPlan, run_stepped_sine, settings_from_config
from ambid.logs import identification_frame
from ambid.machine import machine_from_config
from ambid.mfile import write_thesis_m
from ambid.plant import Plant
from ambid.rig import RigModel, rig_from_config

ROOT = Path(__file__).resolve().parents[1]
TARGET = ROOT / "data/demo20/thesis01/identification.m"
SEED = 11
GRID = {"radial": {"start_hz": 2.0, "stop_hz": 1000.0, "points": 100}, "axial": {"start_hz": 2.0, "stop_hz": 100.0, "points": 50}}
DIGITS = 8


def main():
    rig_config = yaml.safe_load((ROOT / "config/rigs/demo20.yaml").read_text())
    as_built = yaml.safe_load((ROOT / rig_config["as_built"]).read_text())
    planned = copy.deepcopy(as_built)
    planned["frequency_grid"] = GRID
    settings = settings_from_config(yaml.safe_load((ROOT / "config/config.yaml").read_text())["identification"])
    rig_model = RigModel(rig_from_config(rig_config, as_built))
    rig_model = RigModel(rig_model.rig, rig_model.magnetic_center_sensor_m())  # centred, as after calibration
    plan = StepPlan.for_machine(Plant(machine_from_config(planned)), settings)
    records, _ = run_stepped_sine(rig_model, plan, settings, seed=SEED)
    header = [
        "Example identification log of machine demo20 (thesis ch. 5.3 reference rotor), run thesis01.",
        "Adaptive-amplitude stepped sine (thesis ch. 4.2) at the magnetic center, made on ambid's virtual rig",
        f"by tools/example_log.py (seed {SEED}); a real machine's log in this layout goes through the same rules.",
        "One matrix per excited axis, one row per frequency step; U2 = excitation current, V2 = position, I = coil currents.",
    ]
    TARGET.parent.mkdir(parents=True, exist_ok=True)
    write_thesis_m(identification_frame(records), TARGET, header_lines=header, digits=DIGITS)
    print(f"{TARGET.relative_to(ROOT)}: {TARGET.stat().st_size / 1024:.0f} KiB, {plan.step.size} steps")


if __name__ == "__main__":
    main()
