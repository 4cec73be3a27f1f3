"""The ``ambid`` command: a machine file to start from, a look at a log, a log imported, the workflow run.

::

    ambid new-machine NAME --from demo20     # config/machines/NAME.yaml (commented) + its entry in config/config.yaml
    ambid check-log PATH                     # what a log holds: axes, grid, amplitudes, noise, warnings
    ambid import PATH --machine M --run R    # data/M/R/identification.parquet + the run's line in config/config.yaml
    ambid run [snakemake arguments]          # the workflow on the current directory

Everything works on the current directory (``--directory`` elsewhere), which
holds ``config/`` and gets ``data/`` and ``results/``: the repository itself,
or a directory of one's own.  Errors are one line, ``ambid error: ...``, and
exit status 1.
"""

import argparse
import os
import re
import shutil
import sys
import textwrap
from pathlib import Path

import numpy as np
import yaml

from .errors import AmbidError, ConfigError
from .io import atomic_path
from .bla import multisine_passes, realization_levels
from .logs import (CHANNELS, COIL_CURRENT_CHANNELS, has_coil_currents, is_multisine_log, noise_from_scatter,
                   read_multisine_log, repeated_steps, write_identification_log)
from .machine import ALL_AXES, RADIAL_AXES, machine_from_config
from .readers import FORMATS, POSITION_UNITS, detect_format, read_log, read_uff_frf

__all__ = ["main", "new_machine", "check_log", "import_log", "ROOT"]

#: the repository (the library is installed editable from it): templates, schemas, the Snakefile
ROOT = Path(__file__).resolve().parents[2]
_NAME = re.compile(r"^[A-Za-z0-9_]+$")
_KEY_LINE = re.compile(r"^(\s*)(- )?([A-Za-z_]\w*):")


# ---------------------------------------------------------------------------- new-machine
def _resolve(node, schema):
    while isinstance(node, dict) and "$ref" in node:
        node = schema["$defs"][node["$ref"].split("/")[-1]]
    return node if isinstance(node, dict) else {}


def _child(node, key, schema):
    node = _resolve(node, schema)
    properties = node.get("properties", {})
    if key in properties:
        return _resolve(properties[key], schema)
    extra = node.get("additionalProperties")
    return _resolve(extra, schema) if isinstance(extra, dict) else {}


def commented(text, schema):
    """``text`` (a machine file) with the schema's description of each key as a comment above it.

    Keys that already have a comment line right above them keep theirs.
    """
    out, stack = [], []
    for line in text.splitlines():
        match = _KEY_LINE.match(line)
        if match and not line.lstrip().startswith("#"):
            indent = len(match.group(1)) + (2 if match.group(2) else 0)
            while stack and stack[-1][0] >= indent:
                stack.pop()
            parent = stack[-1][1] if stack else schema
            if match.group(2):
                parent = _resolve(_resolve(parent, schema).get("items", {}), schema)
            node = _child(parent, match.group(3), schema)
            description = " ".join(str(node.get("description", "")).split())
            if description and not (out and out[-1].lstrip().startswith("#")):
                prefix = match.group(1) + "# "
                out += textwrap.wrap(description, width=110, initial_indent=prefix, subsequent_indent=prefix)
            stack.append((indent, node))
        out.append(line)
    return "\n".join(out) + "\n"


def _machine_entry(name, template, indent):
    pad = " " * indent
    return (f"{pad}{name}:  # made by `ambid new-machine {name} --from {template}`; keys: config/README.md\n"
            f"{pad}  model: config/machines/{name}.yaml\n"
            f"{pad}  runs: {{}}  # `ambid import LOG --machine {name} --run RUN` adds each run here\n")


def _top_level_block(lines, key):
    """(start, end) line indices of a top-level key's block."""
    start = next((k for k, line in enumerate(lines) if re.match(rf"^{key}:\s*(#.*)?$", line)), None)
    if start is None:
        return None
    end = next((k for k in range(start + 1, len(lines)) if re.match(r"^[A-Za-z_]", lines[k])), len(lines))
    return start, end


def _check_edit(path, text, expected, what):
    """Raise naming what could not be added unless ``text`` (an edit of ``path``) parses to ``expected``."""
    try:
        parsed = yaml.safe_load(text)
    except yaml.YAMLError:
        parsed = None
    if parsed != expected:
        raise ConfigError(what, "could not be added to the file by a text edit that keeps its comments; add it by hand",
                          source=str(path))


def _write_checked(path, text, expected, what):
    """Write ``text`` to ``path`` only if it parses to ``expected``."""
    _check_edit(path, text, expected, what)
    with atomic_path(path) as temporary:
        temporary.write_text(text)


def new_machine(name, template="demo20", directory="."):
    """Write ``config/machines/<name>.yaml`` from a template machine, commented, and its entry in ``config/config.yaml``.

    Parameters
    ----------
    name : str
        The new machine (letters, digits, ``_``).
    template : str
        A machine of the repository (``config/machines/<template>.yaml``) or the path of a machine file.
    directory : str or Path
        The working directory; its ``config/config.yaml`` gets the entry, or is made from the repository's
        (stage settings, no machine but the new one) when there is none.

    Returns
    -------
    list of str
        What was written, one line each.
    """
    if not _NAME.match(name):
        raise ConfigError("NAME", f"{name!r}: a machine name has letters, digits and _ only")
    directory = Path(directory)
    source = Path(template) if Path(template).suffix in (".yaml", ".yml") else ROOT / "config" / "machines" / f"{template}.yaml"
    if not source.is_file():
        known = ", ".join(sorted(p.stem for p in (ROOT / "config" / "machines").glob("*.yaml")))
        raise ConfigError("--from", f"no machine file {source} (shipped: {known})")
    target = directory / "config" / "machines" / f"{name}.yaml"
    if target.exists():
        raise ConfigError("NAME", f"{target} exists; choose another name or remove it")
    config_path = directory / "config" / "config.yaml"
    text = source.read_text()
    machine = yaml.safe_load(text)
    machine["name"] = name
    machine_from_config(machine, name=name, source=str(source))
    text = re.sub(r"^name: .*$", f"name: {name}", text, count=1, flags=re.M)
    with open(ROOT / "workflow" / "schemas" / "machine.schema.yaml") as handle:
        schema = yaml.safe_load(handle)
    header = (f"# Machine model of {name}, made by `ambid new-machine {name} --from {source.stem}`: every value below is\n"
              f"# {source.stem}'s until you replace it by your machine's (SI units, the unit in each key's name;\n"
              f"# config/README.md describes every key).  A schema check runs before every workflow run.\n")
    written, existed = [], config_path.exists()
    if existed:
        lines = config_path.read_text().splitlines(keepends=True)
        config = yaml.safe_load("".join(lines)) or {}
        if name in (config.get("machines") or {}):
            raise ConfigError(f"machines.{name}", "is already in the configuration", source=str(config_path))
        block = _top_level_block(lines, "machines")
        if block is None:
            raise ConfigError("machines", "no top-level machines: block to add to", source=str(config_path))
        first_child = next((line for line in lines[block[0] + 1:block[1]] if _KEY_LINE.match(line)), "  x:")
        indent = len(_KEY_LINE.match(first_child).group(1))
        new_text = "".join(lines[:block[0] + 1]) + _machine_entry(name, source.stem, indent) + "".join(lines[block[0] + 1:])
        expected = {**config, "machines": {**(config.get("machines") or {}),
                                           name: {"model": f"config/machines/{name}.yaml", "runs": {}}}}
    else:
        lines = (ROOT / "config" / "config.yaml").read_text().splitlines(keepends=True)
        start, end = _top_level_block(lines, "machines")
        new_text = "".join(lines[:start + 1]) + _machine_entry(name, source.stem, 2) + "".join(lines[end:])
        expected = {**yaml.safe_load("".join(lines)), "machines": {name: {"model": f"config/machines/{name}.yaml", "runs": {}}}}
    _check_edit(config_path, new_text, expected, f"machines.{name}")  # before anything is written
    with atomic_path(target) as temporary:
        temporary.write_text(header + commented(text, schema))
    written.append(f"wrote {target} (from {source}, every key commented)")
    config_path.parent.mkdir(parents=True, exist_ok=True)
    _write_checked(config_path, new_text, expected, f"machines.{name}")
    written.append(f"{'added' if existed else 'wrote'} machines.{name} in {config_path}")
    return written


# ---------------------------------------------------------------------------- check-log
def _grid(frequency):
    frequency = np.sort(np.asarray(frequency, dtype=float))
    if frequency.size < 2:
        return f"{frequency[0]:.6g} Hz" if frequency.size else "-"
    steps = np.diff(frequency)
    spacing = "linear" if np.allclose(steps, steps.mean(), rtol=0.05) else \
        "logarithmic" if np.allclose(frequency[1:] / frequency[:-1], (frequency[1:] / frequency[:-1]).mean(), rtol=0.05) else "irregular"
    return f"{frequency[0]:.6g}-{frequency[-1]:.6g} Hz, {spacing}"


def _summary_of_log(frame, provenance):
    lines = [f"{provenance['file']}: identification log, format {provenance['format']} ({provenance['layout']}), "
             f"units {provenance['units']}",
             f"{'axis':<5}{'steps':>6}  {'frequency grid':<30}{'amplitude [A]':<26}channels"]
    warnings = list(provenance["notes"])
    grids = {}
    for axis in ALL_AXES:
        part = frame[frame["excited_axis"] == axis]
        if part.empty:
            continue
        per_step = part.groupby("step")[["frequency_hz", "amplitude_a"]].first()
        grids[axis] = per_step["frequency_hz"].to_numpy()
        amplitude = per_step["amplitude_a"]
        lines.append(f"{axis:<5}{len(per_step):>6}  {_grid(grids[axis]):<30}"
                     f"{f'{amplitude.min():.3g}-{amplitude.max():.3g} (median {amplitude.median():.3g})':<26}"
                     f"{part['channel'].nunique()}")
    logged = not (frame["noise_std"] == 0).all()
    if logged:
        noise = frame.groupby("channel")["noise_std"].median()
        lines.append("noise (logged, median per channel):")
    else:
        noise = noise_from_scatter(frame, provenance["file"]).groupby("channel")["noise_std"].first()
        lines.append("noise: none logged; estimated from the scatter between steps, as the FRF stage will:")
        warnings.append("no noise in the log: each channel's noise is estimated from its scatter between steps")
    for prefix, scale, unit in (("V2_", 1e6, "um"), ("U2_", 1.0, "A"), ("I_", 1.0, "A")):
        values = [f"{c.removeprefix(prefix)} {noise[c] * scale:.3g}" for c in CHANNELS if c.startswith(prefix) and c in noise]
        if values:
            lines.append(f"  {prefix.rstrip('_')} [{unit}]: {', '.join(values)}")
    radial = [a for a in RADIAL_AXES if a in grids]
    if len(radial) < len(RADIAL_AXES):
        warnings.append(f"radial axes excited: {', '.join(radial) or 'none'}: no MIMO estimate (needs DX, DY, NX, NY)")
    elif any(grids[a].shape != grids[radial[0]].shape or np.max(np.abs(grids[a] / grids[radial[0]] - 1)) > 1e-6 for a in radial):
        warnings.append("the radial axes are on different frequency grids: no MIMO estimate")
    if "Z" not in grids:
        warnings.append("Z not excited: no axial FRF")
    repeated = repeated_steps(frame)
    if repeated:
        lines.append(f"repeats: {repeated} steps measured again at a lower amplitude (level > 0): the FRF stage "
                     "measures the amplitude dependence from them and takes the FRF to zero amplitude")
    else:
        warnings.append("no step repeated at a lower amplitude (column level): the FRF will be the describing function "
                        "at each step's excitation amplitude, the force law's amplitude-dependent error in it")
    coils = has_coil_currents(frame)
    if not coils:
        warnings.append("no coil currents (I_upper, I_lower): the FRFs will be the positions' alone, and the diagnosis "
                        "cannot tell an amplifier's lag from a sensor's or a delay")
    expected = len(CHANNELS) - (0 if coils else len(COIL_CURRENT_CHANNELS))
    partial = [a for a in grids if frame.loc[frame["excited_axis"] == a, "channel"].nunique() < expected]
    if partial:
        warnings.append(f"steps of {', '.join(partial)} carry their own bearing's channels only: no FRF across bearings "
                        f"(e.g. Z/DX) from them")
    lines.append("warnings:" if warnings else "warnings: none")
    lines += [f"  - {w}" for w in warnings]
    return lines


def _summary_of_frf(table, provenance):
    lines = [f"{provenance['file']}: FRFs (UFF58), estimator(s) {provenance['estimator']}",
             f"{'estimator':<10}{'channel':<10}{'points':>7}  frequency grid"]
    for (estimator, output, input_axis), part in table.groupby(["estimator", "output", "input"], sort=False):
        lines.append(f"{estimator:<10}{output + '/' + input_axis:<10}{len(part):>7}  {_grid(part['frequency_hz'])}")
    lines.append("warnings:")
    lines += [f"  - {note}" for note in provenance["notes"]]
    return lines


def _summary_of_multisine(frame, info, path):
    passes = multisine_passes(frame)
    design = info["metadata"].get("design", "orthogonal")
    lines = [f"{path}: multisine log, design {design}",
             f"{'pass':<8}{'lines':>6}  {'frequency band':<24}{'f0 [Hz]':<10}{'R x E x P':<11}levels"]
    warnings = []
    levels = {item["name"]: np.unique(np.round(realization_levels(item["reference"]), 6)) for item in passes}
    for item in passes:
        realizations, experiments, periods = item["spectra"].shape[:3]
        excited = item["role"] == "excited"
        band = item["frequency_hz"][excited]
        records = f"{realizations} x {experiments} x {periods}"
        lines.append(f"{item['name']:<8}{band.size:>6}  {f'{band.min():.4g}-{band.max():.4g} Hz':<24}"
                     f"{item['frequency_hz'][0] / item['lines'][0]:<10.4g}{records:<11}{', '.join(f'{v:.3g}' for v in levels[item['name']])}")
    coarse = passes[0]
    excited_axes = [a for k, a in enumerate(ALL_AXES) if coarse["excites"][:, k].any()]
    lines.append(f"axes excited: {', '.join(excited_axes)}")
    # the noise of one period's coefficient, from the scatter between periods (what the BLA's noise is made of)
    scatter = np.std(coarse["spectra"], axis=2, ddof=1)  # (R, E, 20, L)
    present = np.isfinite(scatter).all(axis=(0, 1, 3))  # (no coil currents: NaN)
    spread = np.full(len(CHANNELS), np.nan)
    spread[present] = np.median(scatter[:, :, present], axis=(0, 1, 3))
    lines.append("noise (scatter between periods, median per channel and line):")
    for prefix, scale, unit in (("V2_", 1e6, "um"), ("U2_", 1.0, "A"), ("I_", 1.0, "A")):
        values = [f"{c.removeprefix(prefix)} {spread[k] * scale:.3g}" for k, c in enumerate(CHANNELS)
                  if c.startswith(prefix) and np.isfinite(spread[k])]
        if values:
            lines.append(f"  {prefix.rstrip('_')} [{unit}]: {', '.join(values)}")
    if not all(a in excited_axes for a in RADIAL_AXES):
        warnings.append(f"radial axes excited: {', '.join(a for a in RADIAL_AXES if a in excited_axes) or 'none'}: no "
                        "MIMO estimate (needs DX, DY, NX, NY)")
    if "Z" not in excited_axes:
        warnings.append("Z not excited: no axial FRF")
    if coarse["spectra"].shape[0] < 2 and len(levels[coarse["name"]]) < 2:
        warnings.append("one realization at one level: no nonlinear-distortion estimate (the BLA's systematic_std is NaN)")
    if not (coarse["role"] != "excited").any():
        warnings.append("no detection lines: no odd and even distortion levels")
    if not np.isfinite(coarse["spectra"]).all():
        warnings.append("no coil currents (I_upper, I_lower): no coil-current FRF, the excitation level from U2 in their "
                        "place, and the diagnosis cannot tell an amplifier's lag from a sensor's or a delay")
    lines.append("warnings:" if warnings else "warnings: none")
    lines += [f"  - {w}" for w in warnings]
    return lines


def check_log(path, format=None, position_unit=None, current_unit=None, estimator=None):
    """What a log holds, as lines of text (axes, grid, amplitudes, noise, warnings); raises on an invalid log.

    A multisine log (`ambid.logs.MULTISINE_KIND`) is summarized per pass: lines, band, realizations x experiments x
    periods, levels, the noise from the scatter between periods."""
    format = format or detect_format(path)
    if format == "parquet" and is_multisine_log(path):
        frame, info = read_multisine_log(path)
        return _summary_of_multisine(frame, info, path)
    if format == "uff":
        options = {k: v for k, v in (("estimator", estimator), ("position_unit", position_unit),
                                     ("current_unit", current_unit)) if v}
        return _summary_of_frf(*read_uff_frf(path, **options))
    return _summary_of_log(*read_log(path, format, position_unit, current_unit))


# ---------------------------------------------------------------------------- import
def _flow(mapping):
    return "{" + ", ".join(f"{key}: {value}" for key, value in mapping.items()) + "}"


def add_run(config_path, machine, run, spec):
    """Add ``machines.<machine>.runs.<run>: spec`` to a config file by a text edit that keeps its comments."""
    config_path = Path(config_path)
    text = config_path.read_text()
    config = yaml.safe_load(text) or {}
    entry = (config.get("machines") or {}).get(machine)
    if entry is None:
        raise ConfigError(f"machines.{machine}", f"not in the configuration: `ambid new-machine {machine} --from demo20` "
                                                 f"first", source=str(config_path))
    if run in (entry.get("runs") or {}):
        raise ConfigError(f"machines.{machine}.runs.{run}", "is already in the configuration", source=str(config_path))
    lines = text.splitlines(keepends=True)
    start, end = _top_level_block(lines, "machines")
    at = next(k for k in range(start + 1, end) if re.match(rf"^\s+{machine}:", lines[k]))
    own = len(lines[at]) - len(lines[at].lstrip())
    stop = next((k for k in range(at + 1, end) if lines[k].strip() and not lines[k].lstrip().startswith("#")
                 and len(lines[k]) - len(lines[k].lstrip()) <= own), end)
    runs = next((k for k in range(at + 1, stop) if re.match(r"^\s+runs:", lines[k])), None)
    child = next((len(lines[k]) - len(lines[k].lstrip()) for k in range(at + 1, stop) if _KEY_LINE.match(lines[k])), own + 2)
    line = f"{' ' * (child + 2)}{run}: {_flow(spec)}\n"
    if runs is None:
        lines.insert(at + 1, f"{' ' * child}runs:\n{line}")
    else:
        match = re.match(r"^(\s+runs:)\s*(\{\s*\})?\s*(#.*)?$", lines[runs].rstrip("\n"))
        if match is None:  # a flow mapping with runs in it: left to the check below
            lines.insert(runs + 1, line)
        else:
            lines[runs] = f"{match.group(1)}{'  ' + match.group(3) if match.group(3) else ''}\n"
            lines.insert(runs + 1, line)
    expected = {**config, "machines": {**config["machines"], machine: {**entry, "runs": {**(entry.get("runs") or {}), run: spec}}}}
    _write_checked(config_path, "".join(lines), expected, f"machines.{machine}.runs.{run}: {_flow(spec)}")
    return f"{config_path}: added machines.{machine}.runs.{run}: {_flow(spec)}"


def import_log(path, machine, run, format=None, position_unit=None, current_unit=None, estimator=None, directory=".",
               force=False):
    """Convert a user's log once into ``data/<machine>/<run>/`` and declare the run in ``config/config.yaml``.

    A log in any reader format (`ambid.readers.FORMATS`) becomes the canonical
    ``identification.parquet`` (with its provenance); UFF58 FRFs are checked and
    copied to ``frf.uff`` (run format ``uff``: they feed the FRF stage directly).

    Returns
    -------
    list of str
        What was written, one line each.
    """
    for value, what in ((machine, "--machine"), (run, "--run")):
        if not _NAME.match(value):
            raise ConfigError(what, f"{value!r}: letters, digits and _ only")
    directory = Path(directory)
    format = format or detect_format(path)
    folder = directory / "data" / machine / run
    units = {k: v for k, v in (("position_unit", position_unit), ("current_unit", current_unit)) if v}
    spec = {"kind": "identification", "source": "data"}
    if format == "uff":
        table, provenance = read_uff_frf(path, **units, **({"estimator": estimator} if estimator else {}))
        target = folder / "frf.uff"
        spec.update(format="uff", **units, **({"estimator": estimator} if estimator else {}))
        done = f"checked {path} ({len(table)} FRF points) and copied it to {target}"
    else:
        frame, provenance = read_log(path, format, position_unit, current_unit)
        target = folder / "identification.parquet"
        done = f"wrote {target} ({frame.groupby(['excited_axis', 'step']).ngroups} steps, axes " \
               f"{', '.join(a for a in ALL_AXES if a in set(frame['excited_axis']))}; from {path}, {provenance['format']})"
    if target.exists() and Path(path).resolve() == target.resolve():
        raise ConfigError("PATH", f"{path} is the file the import would write: move it elsewhere first (nothing is lost)")
    if target.exists() and not force:
        raise ConfigError("--run", f"{target} exists (--force replaces it)")
    if format == "uff":
        target.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(target) as temporary:
            shutil.copyfile(path, temporary)
    else:
        write_identification_log(frame, target, {"machine": machine, "run": run, "provenance": provenance})
    lines = [done] + [f"note: {note}" for note in provenance["notes"]]
    config_path = directory / "config" / "config.yaml"
    entry = f"{run}: {_flow(spec)}"
    try:
        lines.append(add_run(config_path, machine, run, spec))
    except (ConfigError, OSError) as error:
        lines.append(f"the run's line for config/config.yaml, under machines.{machine}.runs ({error}):")
        lines.append(f"  {entry}")
    return lines


# ---------------------------------------------------------------------------- main
def _parser():
    parser = argparse.ArgumentParser(prog="ambid", description=__doc__.split("\n\n")[0])
    parser.add_argument("--directory", "-d", default=".", help="working directory (holds config/; default: .)")
    commands = parser.add_subparsers(dest="command", required=True)
    new = commands.add_parser("new-machine", help="a commented machine file from a template and its config entry")
    new.add_argument("name")
    new.add_argument("--from", dest="template", default="demo20", help="shipped machine or a machine file (default demo20)")

    def reader_options(command):
        command.add_argument("--format", choices=FORMATS, help="default: from the file name")
        command.add_argument("--position-unit", choices=sorted(POSITION_UNITS), help="unit of positions in a table or UFF file")
        command.add_argument("--current-unit", choices=["A", "mA"], help="unit of currents in a table or UFF file")
        command.add_argument("--estimator", choices=["siso", "mimo"], help="UFF from another writer: what its FRFs are")

    check = commands.add_parser("check-log", help="validate a log and print what it holds")
    check.add_argument("path")
    reader_options(check)
    imp = commands.add_parser("import", help="convert a log into data/<machine>/<run>/ and declare the run")
    imp.add_argument("path")
    imp.add_argument("--machine", required=True)
    imp.add_argument("--run", required=True)
    imp.add_argument("--force", action="store_true", help="replace the run's existing log")
    reader_options(imp)
    run = commands.add_parser("run", help="the workflow on the working directory (snakemake arguments follow)")
    run.add_argument("snakemake_arguments", nargs=argparse.REMAINDER)
    return parser


def main(argv=None):
    """Entry point of the ``ambid`` console script."""
    parser = _parser()
    arguments, unknown = parser.parse_known_args(argv)
    if unknown and arguments.command != "run":
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    try:
        if arguments.command == "new-machine":
            lines = new_machine(arguments.name, arguments.template, arguments.directory)
        elif arguments.command == "check-log":
            lines = check_log(arguments.path, arguments.format, arguments.position_unit, arguments.current_unit,
                              arguments.estimator)
        elif arguments.command == "import":
            lines = import_log(arguments.path, arguments.machine, arguments.run, arguments.format, arguments.position_unit,
                               arguments.current_unit, arguments.estimator, arguments.directory, arguments.force)
        else:
            extra = unknown + arguments.snakemake_arguments
            command = [sys.executable, "-m", "snakemake", "-s", str(ROOT / "Snakefile"), "-d", str(arguments.directory)]
            command += extra if any(a.startswith(("--cores", "-c")) for a in extra) else ["--cores", "2", *extra]
            os.execv(sys.executable, command)
    except AmbidError as error:
        print(f"ambid error: {error}", file=sys.stderr)
        return 1
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
