"""Mode tables: open-loop plant modes and closed-loop modes of a machine.

The open-loop plant (bearings' negative stiffness, no controller) has the
unstable rigid-body pole pairs ``+-a`` that an AMB plant must show, and the
lightly damped flexible modes that identification measures.  The closed loop
(sampled-data, with the digital controllers) has the suspension modes the
operator sees.  Each mode is classified rigid / flexible / foundation by where
its energy lies, and forward / backward by the orbit of the rotor.  Real
closed-loop poles (integrators, filters, overdamped suspension) are
"overdamped"; ``plant_participation`` (participation factors of the plant
states) tells structural modes from controller and filter poles.  At standstill the
x and y planes have identical modes: they are listed once with multiplicity 2
and whirl "planar".
"""

import numpy as np

from .plant import damping_ratio

__all__ = ["mode_table"]


def mode_table(plant, max_frequency_hz=None):
    """Modes of the open-loop plant and of the closed loop.

    Parameters
    ----------
    plant : ambid.plant.Plant
    max_frequency_hz : float, optional
        Keep modes up to this frequency (default: the controller's Nyquist frequency).

    Returns
    -------
    list of dict
        ``system`` (open_loop / closed_loop), ``frequency_hz`` (undamped natural
        frequency |s| / 2 pi), ``damped_frequency_hz`` (Im s / 2 pi),
        ``damping_ratio`` (negative = unstable), ``real_part_1_per_s``, ``kind``
        (rigid / flexible / foundation / overdamped), ``whirl`` (forward /
        backward / planar; none for real poles), ``multiplicity``,
        ``plant_participation`` (1 for open-loop modes), ``speed_rpm``.
        Complex-conjugate pairs appear once (Im s >= 0); sorted by system and
        frequency.
    """
    machine = plant.machine
    if max_frequency_hz is None:
        max_frequency_hz = 0.5 / machine.sample_time_s
    poles, vectors = plant.poles()
    rows = _rows("open_loop", plant, poles, vectors, np.ones(poles.size), max_frequency_hz)
    closed = plant.closed_loop_poles()
    finite = np.isfinite(closed.s_poles)  # the delay buffer's poles at z = 0 have no frequency
    rows += _rows("closed_loop", plant, closed.s_poles[finite], closed.vectors[:, finite], closed.plant_participation[finite],
                  max_frequency_hz)
    rows.sort(key=lambda r: (r["system"] != "open_loop", r["frequency_hz"], r["real_part_1_per_s"]))
    return rows


def _rows(system, plant, poles, vectors, plant_participation, max_frequency_hz):
    n_q = plant.radial.mass.shape[0]
    speed_rpm = plant.machine.speed_rad_s * 60 / (2 * np.pi)
    zeta = damping_ratio(poles)
    rows, seen = [], []
    for k, pole in enumerate(poles):
        scale = max(abs(pole), 1.0)
        if pole.imag < -1e-9 * scale or abs(pole) / (2 * np.pi) > max_frequency_hz:
            continue
        duplicate = next((r for r, p in seen if abs(p - pole) <= 1e-6 * scale), None)
        if duplicate is not None:
            duplicate["multiplicity"] += 1
            continue
        kind, whirl = plant.mode_kind(vectors[:n_q, k])
        if abs(pole.imag) <= 1e-9 * scale:
            pole = complex(pole.real, 0.0)
            kind, whirl = ("overdamped" if system == "closed_loop" else kind), "none"
        elif plant.machine.speed_rad_s == 0:
            whirl = "planar"
        row = {
            "system": system,
            "frequency_hz": float(abs(pole) / (2 * np.pi)),
            "damped_frequency_hz": float(abs(pole.imag) / (2 * np.pi)),
            "damping_ratio": float(zeta[k]),
            "real_part_1_per_s": float(pole.real),
            "kind": kind,
            "whirl": whirl,
            "multiplicity": 1,
            "plant_participation": float(plant_participation[k]),
            "speed_rpm": float(speed_rpm),
        }
        rows.append(row)
        seen.append((row, pole))
    return rows
