"""ambid: identification and model updating of active magnetic bearing systems.

The physics (rotor FEM, bearing force law, controller, plant, effects) and the
stages of the workflow (identification, fitting, updating, diagnosis) as a
library that never imports Snakemake; the workflow's rule scripts call it.
See DESIGN notes in the README for the map of modules.
"""

__version__ = "0.1.0"
