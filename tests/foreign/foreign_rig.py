#!/usr/bin/env python
"""foreign_rig: an independent virtual AMB test rig writing stepped-sine identification logs.

Written from the machine-file key reference, the log contract of ambid's README ("Bring your own
logs", plain-table layout) and the thesis (rotor FEM ch. 2, force law eq. 3.2-3.6, ISO 14839-3
excitation at the controller output E_u, adaptive stepped sine ch. 4.2).  Shares no code with ambid.

Usage:
  python foreign_rig.py --machine demo20.yaml --out DIR --seed 1 [--effects JSON]
         [--layout wide|long] [--position-unit um|mm|m] [--current-unit A|mA] [--noise-scale 1]

See README.md next to this file for every convention.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import scipy.linalg as sla
import scipy.signal as ssig
import yaml

MU0 = 4e-7 * math.pi
RADIAL = ["DX", "DY", "NX", "NY"]
PLANE = {"DX": 0, "DY": 1, "NX": 0, "NY": 1}      # 0: x-z plane, 1: y-z plane
BEARING = {"DX": "DE", "DY": "DE", "NX": "NDE", "NY": "NDE"}
PARTNER = {"DX": "DY", "DY": "DX", "NX": "NY", "NY": "NX"}

KNOWN_EFFECTS = {
    "delay", "amplifier_lowpass", "sensor_lowpass", "eddy_current", "element_stiffness",
    "modal_damping", "gyroscopic", "noncollocation", "foundation_mode", "cross_coupling",
    "amplifier_second_order", "sensor_gain", "xy_anisotropy", "housing_coupled",
}


# ----------------------------------------------------------------------------------------------
# Rotor: Timoshenko beam FEM
# ----------------------------------------------------------------------------------------------
def shear_coefficient(nu, di, do):
    """Hutchinson/Cowper shear coefficient of a hollow circular section."""
    m = di / do
    m2 = m * m
    return 6 * (1 + nu) * (1 + m2) ** 2 / ((7 + 6 * nu) * (1 + m2) ** 2 + (20 + 12 * nu) * m2)


def timoshenko_element(L, EI, kGA, mu, rhoI):
    """Per-plane element matrices, DOFs [w1, th1, w2, th2] (th = slope-like cross-section rotation).

    Returns stiffness K, mass M (translational + rotary) and the rotary part Mr (for gyroscopics).
    Interdependent interpolation (Friedman & Kosmatka 1993)."""
    phi = 12 * EI / (kGA * L * L)
    c = EI / (L ** 3 * (1 + phi))
    K = c * np.array([
        [12, 6 * L, -12, 6 * L],
        [6 * L, (4 + phi) * L * L, -6 * L, (2 - phi) * L * L],
        [-12, -6 * L, 12, -6 * L],
        [6 * L, (2 - phi) * L * L, -6 * L, (4 + phi) * L * L]])
    p2 = phi * phi
    a = 13 / 35 + 7 * phi / 10 + p2 / 3
    b = (11 / 210 + 11 * phi / 120 + p2 / 24) * L
    cc = 9 / 70 + 3 * phi / 10 + p2 / 6
    d = (13 / 420 + 3 * phi / 40 + p2 / 24) * L
    e = (1 / 105 + phi / 60 + p2 / 120) * L * L
    f = (1 / 140 + phi / 60 + p2 / 120) * L * L
    Mt = mu * L / (1 + phi) ** 2 * np.array([
        [a, b, cc, -d],
        [b, e, d, -f],
        [cc, d, a, -b],
        [-d, -f, -b, e]])
    g = 6 / 5
    h = (1 / 10 - phi / 2) * L
    i = (2 / 15 + phi / 6 + p2 / 3) * L * L
    j = (-1 / 30 - phi / 6 + p2 / 6) * L * L
    Mr = rhoI / (L * (1 + phi) ** 2) * np.array([
        [g, h, -g, h],
        [h, i, -h, j],
        [-g, -h, g, -h],
        [h, j, -h, i]])
    return K, Mt + Mr, Mr


class Rotor:
    """Free-free rotor FEM, one plane (the x-z and y-z planes are identical)."""

    def __init__(self, machine, effects, n_sub=2, extra_positions=()):
        mats = machine["materials"]
        rot = machine["rotor"]
        # expand elements
        elems = []
        for e in rot["elements"]:
            for _ in range(int(e.get("repeat", 1))):
                elems.append(dict(e))
        self.n_orig = len(elems)
        z_b = np.concatenate([[0.0], np.cumsum([e["length_m"] for e in elems])])
        self.z_boundaries = z_b
        self.length = float(z_b[-1])
        # stiffness scale per original element (effect element_stiffness)
        escale = np.ones(len(elems))
        for eff in effects:
            if eff["name"] == "element_stiffness":
                tag = eff["tag"]
                idx = [k for k, e in enumerate(elems) if tag in (e.get("tags") or [])]
                if not idx:
                    raise SystemExit(f"element_stiffness: no element carries tag {tag!r}")
                sc = eff["scale"]
                sc = [sc] * len(idx) if np.isscalar(sc) else list(sc)
                if len(sc) != len(idx):
                    raise SystemExit(f"element_stiffness: {len(sc)} scales for {len(idx)} elements of {tag!r}")
                for k, s in zip(idx, sc):
                    escale[k] *= float(s)
        self.escale = escale
        sleeves = rot.get("sleeves") or []
        # mesh: split original elements at extra positions and into n_sub parts
        cuts = sorted(set(float(p) for p in extra_positions))
        nodes_z = []
        sub = []   # (original element index, z0, z1)
        for k, e in enumerate(elems):
            z0, z1 = z_b[k], z_b[k + 1]
            pts = [z0, z1] + [p for p in cuts if z0 + 1e-12 < p < z1 - 1e-12]
            pts = sorted(pts)
            fine = []
            for a, b in zip(pts[:-1], pts[1:]):
                for s in range(n_sub):
                    fine.append((a + (b - a) * s / n_sub, a + (b - a) * (s + 1) / n_sub))
            for a, b in fine:
                sub.append((k, a, b))
        self.node_z = np.array([sub[0][1]] + [s[2] for s in sub])
        nn = len(self.node_z)
        ndof = 2 * nn
        K = np.zeros((ndof, ndof))
        M = np.zeros((ndof, ndof))
        Mr = np.zeros((ndof, ndof))
        matnames = sorted(mats)
        Kmat = {m: np.zeros((ndof, ndof)) for m in matnames}
        self.mass = 0.0
        for s, (k, a, b) in enumerate(sub):
            e = elems[k]
            mat = mats[e["material"]]
            E = float(mat["youngs_modulus_pa"])
            rho = float(mat["density_kg_m3"])
            nu = float(mat.get("poisson_ratio", 0.3))
            G = float(mat["shear_modulus_pa"]) if "shear_modulus_pa" in mat else E / (2 * (1 + nu))
            do = float(e["outer_diameter_m"])
            di = float(e.get("inner_diameter_m", 0.0) or 0.0)
            A = math.pi / 4 * (do ** 2 - di ** 2)
            I = math.pi / 64 * (do ** 4 - di ** 4)
            mu = rho * A
            rhoI = rho * I
            EI = E * I
            GA = G * A
            for sl in sleeves:
                if sl["tag"] in (e.get("tags") or []):
                    so = float(sl["outer_diameter_m"])
                    si = float(sl.get("inner_diameter_m", 0.0) or 0.0)
                    As = math.pi / 4 * (so ** 2 - si ** 2)
                    Is = math.pi / 64 * (so ** 4 - si ** 4)
                    rs = float(sl["density_kg_m3"])
                    mu += rs * As
                    rhoI += rs * Is
                    fr = float(sl.get("stiffness_fraction", 0.0) or 0.0)
                    Es = float(sl.get("youngs_modulus_pa", E))
                    EI += fr * Es * Is
                    GA += fr * (Es / E) * G * As
            EI *= escale[k]          # element_stiffness: Young's modulus scaled, G kept
            kGA = shear_coefficient(nu, di, do) * GA
            L = b - a
            Ke, Me, Mre = timoshenko_element(L, EI, kGA, mu, rhoI)
            dofs = [2 * s, 2 * s + 1, 2 * s + 2, 2 * s + 3]
            ix = np.ix_(dofs, dofs)
            K[ix] += Ke
            M[ix] += Me
            Mr[ix] += Mre
            Kmat[e["material"]][ix] += Ke
            self.mass += mu * L
        Gy = 2.0 * Mr                         # polar = 2 x diametral for the distributed part
        self.Ip_total = 0.0
        for d in rot.get("disks") or []:
            zd = z_b[int(d["node"])]
            nd = self.node_at(zd)
            M[2 * nd, 2 * nd] += float(d["mass_kg"])
            M[2 * nd + 1, 2 * nd + 1] += float(d["transverse_inertia_kg_m2"])
            Gy[2 * nd + 1, 2 * nd + 1] += float(d["polar_inertia_kg_m2"])
            self.mass += float(d["mass_kg"])
        self.K, self.M, self.G, self.Kmat = K, M, Gy, Kmat
        self.loss = {m: float(mats[m].get("loss_factor", 0.0) or 0.0) for m in matnames}
        self.ndof = ndof
        self.n_elements = len(sub)

    def node_at(self, z):
        k = int(np.argmin(np.abs(self.node_z - z)))
        if abs(self.node_z[k] - z) > 1e-9:
            raise SystemExit(f"no node at z = {z}")
        return k

    def modes(self, added_damping=0.0):
        w2, Phi = sla.eigh(self.K, self.M)
        w2 = np.clip(w2, 0.0, None)
        w = np.sqrt(w2)
        wmax = w.max()
        rigid = w < 1e-6 * wmax + 1.0            # rad/s: rigid-body modes
        zeta = np.zeros_like(w)
        for r in np.where(~rigid)[0]:
            ph = Phi[:, r]
            ktot = ph @ self.K @ ph
            zeta[r] = sum(self.loss[m] / 2 * (ph @ self.Kmat[m] @ ph) / ktot for m in self.Kmat)
        zeta[~rigid] += added_damping
        return w, Phi, zeta, rigid


# ----------------------------------------------------------------------------------------------
# Electromagnet linearization, thesis eq. 3.2-3.6
# ----------------------------------------------------------------------------------------------
def magnet_coefficients(em):
    th = math.radians(float(em.get("pole_angle_deg", 22.5)))
    k = MU0 * float(em["pole_area_m2"]) * float(em["turns"]) ** 2 * math.cos(th)
    g0 = float(em["nominal_air_gap_m"])
    b = float(em.get("iron_path_m", 0.0))
    ib = float(em["bias_current_a"])
    s = 2 * g0 + b
    # F = k[(ib+i)^2/(2(g0-x c)+b)^2 - (ib-i)^2/(2(g0+x c)+b)^2]; d/di, d/dx at x=0, i=0
    ki = 4 * k * ib / s ** 2
    kx = 8 * k * math.cos(th) * ib ** 2 / s ** 3
    return ki, kx, ib


# ----------------------------------------------------------------------------------------------
# Small SISO LTI helpers
# ----------------------------------------------------------------------------------------------
def lti_first_order(wc):
    return np.array([[-wc]]), np.array([[wc]]), np.array([[1.0]]), np.array([[0.0]])


def lti_second_order(wn, z):
    return (np.array([[0.0, 1.0], [-wn * wn, -2 * z * wn]]), np.array([[0.0], [wn * wn]]),
            np.array([[1.0, 0.0]]), np.array([[0.0]]))


def lti_identity():
    return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[1.0]])


def lti_series(a, b):
    """a then b (SISO)."""
    A1, B1, C1, D1 = a
    A2, B2, C2, D2 = b
    n1, n2 = A1.shape[0], A2.shape[0]
    A = np.zeros((n1 + n2, n1 + n2))
    A[:n1, :n1] = A1
    A[n1:, :n1] = B2 @ C1
    A[n1:, n1:] = A2
    B = np.vstack([B1, B2 @ D1])
    C = np.hstack([D2 @ C1, C2])
    D = D2 @ D1
    return A, B, C, D


def lti_blockdiag(blocks):
    A = sla.block_diag(*[b[0] for b in blocks]) if blocks else np.zeros((0, 0))
    n = sum(b[0].shape[0] for b in blocks)
    m = len(blocks)
    B = np.zeros((n, m))
    C = np.zeros((m, n))
    D = np.zeros((m, m))
    o = 0
    for k, (Ak, Bk, Ck, Dk) in enumerate(blocks):
        nk = Ak.shape[0]
        B[o:o + nk, k] = Bk[:, 0]
        C[k, o:o + nk] = Ck[0, :]
        D[k, k] = Dk[0, 0]
        o += nk
    A = np.asarray(A).reshape(n, n)
    return A, B, C, D


def axes_of(eff, default):
    ax = eff.get("axes")
    return list(default) if ax is None else [a for a in ax if a in default]


# ----------------------------------------------------------------------------------------------
# Continuous plant (DAC output -> coil currents, force, positions) as a state space
# ----------------------------------------------------------------------------------------------
class ContinuousPlant:
    """x' = A x + B u;  positions r = Cy x (before the ADC);  coil currents i = Ci x + Di u."""

    def __init__(self, A, B, Cy, Ci, Di, delays, axes, info):
        self.A, self.B, self.Cy, self.Ci, self.Di = A, B, Cy, Ci, Di
        self.delays = np.asarray(delays, float)
        self.axes = axes
        self.info = info


def actuator_chain(axes, effects):
    """Per axis: amplifier (command -> coil current) and eddy (coil current -> force current)."""
    amp, edd = [], []
    for a in axes:
        am = lti_identity()
        ed = lti_identity()
        for eff in effects:
            n = eff["name"]
            if n == "amplifier_lowpass" and a in axes_of(eff, axes):
                am = lti_series(am, lti_first_order(2 * math.pi * float(eff["cutoff_hz"])))
            elif n == "amplifier_second_order" and a in axes_of(eff, axes):
                am = lti_series(am, lti_second_order(2 * math.pi * float(eff["natural_hz"]),
                                                      float(eff["damping_ratio"])))
            elif n == "eddy_current" and a in axes_of(eff, axes):
                ed = lti_series(ed, lti_first_order(2 * math.pi * float(eff["corner_hz"])))
        amp.append(am)
        edd.append(ed)
    return lti_blockdiag(amp), lti_blockdiag(edd)


def sensor_chain(axes, effects):
    blocks = []
    for a in axes:
        s = lti_identity()
        for eff in effects:
            if eff["name"] == "sensor_lowpass" and a in axes_of(eff, axes):
                wc = 2 * math.pi * float(eff["cutoff_hz"])
                if int(eff.get("order", 1)) == 2:
                    s = lti_series(s, lti_second_order(wc, 1 / math.sqrt(2)))
                else:
                    s = lti_series(s, lti_first_order(wc))
        blocks.append(s)
    return lti_blockdiag(blocks)


def assemble(Mq, Dq, Kq, Rel_act, Rel_sens, Kx, Ki, scale, amp, edd, sens, Jin, Sout):
    """Mechanical second-order system in coordinates q (with per-coordinate scaling) plus chains.

    Force on axis k: F_k = Kx_k (Rel_act q)_k + Ki_k f_k, generalized force Rel_act^T F;
    f = Jin * (force current after eddy lag); positions r = Sout Rel_sens q -> sensor chain."""
    nq = Mq.shape[0]
    na = len(Kx)
    Minv = np.linalg.inv(Mq)
    Ktot = Kq - Rel_act.T @ np.diag(Kx) @ Rel_act
    Bf = Rel_act.T @ np.diag(Ki)
    S = np.diag(scale)
    Sinv = np.diag(1.0 / scale)
    # mechanical states [p = S q, v = q']
    Am = np.block([[np.zeros((nq, nq)), S], [-Minv @ Ktot @ Sinv, -Minv @ Dq]])
    Bm = np.vstack([np.zeros((nq, na)), Minv @ Bf])
    Cr = np.hstack([Rel_sens @ Sinv, np.zeros((na, nq))])
    Aa, Ba, Ca, Da = amp
    Ae, Be, Ce, De = edd
    As, Bs, Cs, Ds = sens
    nm, nA, nE, nS = Am.shape[0], Aa.shape[0], Ae.shape[0], As.shape[0]
    n = nm + nA + nE + nS
    A = np.zeros((n, n))
    B = np.zeros((n, na))
    im, ia, ie, is_ = slice(0, nm), slice(nm, nm + nA), slice(nm + nA, nm + nA + nE), slice(nm + nA + nE, n)
    # force current f = Jin (Ce xe + De (Ca xa + Da u))
    A[im, im] = Am
    A[im, ia] = Bm @ Jin @ De @ Ca
    A[im, ie] = Bm @ Jin @ Ce
    B[im, :] = Bm @ Jin @ De @ Da
    A[ia, ia] = Aa
    B[ia, :] = Ba
    A[ie, ia] = Be @ Ca
    A[ie, ie] = Ae
    B[ie, :] = Be @ Da
    A[is_, im] = Bs @ Sout @ Cr
    A[is_, is_] = As
    Cy = np.zeros((na, n))
    Cy[:, im] = Ds @ Sout @ Cr
    Cy[:, is_] = Cs
    Ci = np.zeros((na, n))
    Ci[:, ia] = Ca
    Di = Da.copy()
    return A, B, Cy, Ci, Di


def radial_plant(machine, effects, n_sub):
    br = machine["bearings"]["radial"]
    de, nde = br["DE"], br["NDE"]
    act = {"DE": float(de["actuator_position_m"]), "NDE": float(nde["actuator_position_m"])}
    sen = {"DE": float(de.get("sensor_position_m", de["actuator_position_m"])),
           "NDE": float(nde.get("sensor_position_m", nde["actuator_position_m"]))}
    for eff in effects:
        if eff["name"] == "noncollocation":
            sen["DE"] += float(eff.get("de_offset_m", 0.0))
            sen["NDE"] += float(eff.get("nde_offset_m", 0.0))
    rotor = Rotor(machine, effects, n_sub=n_sub, extra_positions=list(act.values()) + list(sen.values()))
    added = sum(float(np.mean(np.atleast_1d(e["damping_ratio"]))) for e in effects if e["name"] == "modal_damping")
    w, Phi, zeta, rigid = rotor.modes(added_damping=added)
    nmod = len(w)
    speed = sum(float(e["speed_rpm"]) for e in effects if e["name"] == "gyroscopic") * 2 * math.pi / 60
    ki0, kx0, ib = magnet_coefficients(br["electromagnet"])
    Ki = np.full(4, ki0)
    Kx = np.full(4, kx0)
    for eff in effects:
        if eff["name"] == "xy_anisotropy":
            f = float(eff["factor"])
            for k, a in enumerate(RADIAL):
                if PLANE[a] == 1:
                    Ki[k] *= f
                    Kx[k] *= f
    # housings
    hous = []     # (name, mass, k, c, axes it carries)
    for eff in effects:
        if eff["name"] == "foundation_mode":
            m = float(eff["mass_kg"])
            kk = m * (2 * math.pi * float(eff["frequency_hz"])) ** 2
            c = 2 * float(eff["damping_ratio"]) * math.sqrt(kk * m)
            for a in RADIAL:
                hous.append((f"housing_{a}", m, kk, c, [a]))
        elif eff["name"] == "housing_coupled":
            m = float(eff["mass_kg"])
            kk = m * (2 * math.pi * float(eff["frequency_hz"])) ** 2
            c = 2 * float(eff["damping_ratio"]) * math.sqrt(kk * m)
            hous.append(("frame_x", m, kk, c, ["DX", "NX"]))
            hous.append(("frame_y", m, kk, c, ["DY", "NY"]))
    nh = len(hous)
    nq = 2 * nmod + nh
    # coordinates: modal eta_x (nmod), eta_y (nmod), housings
    Mq = np.eye(nq)
    Kq = np.zeros((nq, nq))
    Dq = np.zeros((nq, nq))
    lam = np.diag(w ** 2)
    dm = np.diag(2 * zeta * w)
    Gm = Phi.T @ rotor.G @ Phi
    X, Y = slice(0, nmod), slice(nmod, 2 * nmod)
    Kq[X, X] = lam
    Kq[Y, Y] = lam
    Dq[X, X] = dm
    Dq[Y, Y] = dm
    # spin +Omega about +z, slopes as rotation DOFs: x-plane + Omega G y', y-plane - Omega G x'
    Dq[X, Y] += speed * Gm
    Dq[Y, X] -= speed * Gm
    scale = np.concatenate([np.maximum(w, 2 * math.pi * 50.0)] * 2 + [np.ones(0)])
    hscale = []
    for j, (_, m, kk, c, _) in enumerate(hous):
        Mq[2 * nmod + j, 2 * nmod + j] = m
        Kq[2 * nmod + j, 2 * nmod + j] = kk
        Dq[2 * nmod + j, 2 * nmod + j] = c
        hscale.append(math.sqrt(kk / m))
    scale = np.concatenate([scale, np.array(hscale)])
    Rel_act = np.zeros((4, nq))
    Rel_sens = np.zeros((4, nq))
    for k, a in enumerate(RADIAL):
        pl = X if PLANE[a] == 0 else Y
        na_ = rotor.node_at(act[BEARING[a]])
        ns_ = rotor.node_at(sen[BEARING[a]])
        Rel_act[k, pl] = Phi[2 * na_, :]
        Rel_sens[k, pl] = Phi[2 * ns_, :]
        for j, h in enumerate(hous):
            if a in h[4]:
                Rel_act[k, 2 * nmod + j] -= 1.0
                Rel_sens[k, 2 * nmod + j] -= 1.0
    Jin = np.eye(4)
    Sout = np.eye(4)
    J = np.zeros((4, 4))
    for k, a in enumerate(RADIAL):
        J[k, RADIAL.index(PARTNER[a])] = 1.0
    for eff in effects:
        if eff["name"] == "cross_coupling":
            c = float(eff["coefficient"])
            if eff.get("side", "input") == "input":
                Jin = Jin + c * J
            else:
                Sout = (np.eye(4) + c * J) @ Sout
    for eff in effects:
        if eff["name"] == "sensor_gain" and eff["axis"] in RADIAL:
            k = RADIAL.index(eff["axis"])
            Sout[k, :] *= float(eff["gain"])
    amp, edd = actuator_chain(RADIAL, effects)
    sens = sensor_chain(RADIAL, effects)
    A, B, Cy, Ci, Di = assemble(Mq, Dq, Kq, Rel_act, Rel_sens, Kx, Ki, scale, amp, edd, sens, Jin, Sout)
    delays = np.zeros(4)
    for eff in effects:
        if eff["name"] == "delay":
            for a in axes_of(eff, RADIAL):
                delays[RADIAL.index(a)] += float(eff["delay_s"])
    info = dict(ki_a=Ki.tolist(), kx_n_per_m=Kx.tolist(), bias_current_a=ib,
                rotor_mass_kg=rotor.mass, n_fe_elements=rotor.n_elements, n_fe_nodes=len(rotor.node_z),
                free_free_hz=(w[~rigid] / 2 / math.pi)[:6].tolist(),
                modal_damping_ratio=zeta[~rigid][:6].tolist(),
                actuator_positions_m=act, sensor_positions_m=sen, speed_rad_s=speed,
                housings=[dict(name=h[0], mass_kg=h[1], stiffness_n_per_m=h[2], damping_n_s_per_m=h[3],
                               axes=h[4]) for h in hous])
    return ContinuousPlant(A, B, Cy, Ci, Di, delays, RADIAL, info), rotor


def axial_plant(machine, effects, rotor_mass):
    ki, kx, ib = magnet_coefficients(machine["bearings"]["axial"]["electromagnet"])
    Mq = np.array([[rotor_mass]])
    Kq = np.zeros((1, 1))
    Dq = np.zeros((1, 1))
    R = np.array([[1.0]])
    amp, edd = actuator_chain(["Z"], effects)
    sens = sensor_chain(["Z"], effects)
    Sout = np.eye(1)
    for eff in effects:
        if eff["name"] == "sensor_gain" and eff["axis"] == "Z":
            Sout *= float(eff["gain"])
    A, B, Cy, Ci, Di = assemble(Mq, Dq, Kq, R, R, np.array([kx]), np.array([ki]),
                                np.array([math.sqrt(kx / rotor_mass)]), amp, edd, sens, np.eye(1), Sout)
    delays = np.zeros(1)
    for eff in effects:
        if eff["name"] == "delay" and "Z" in axes_of(eff, ["DX", "DY", "NX", "NY", "Z"]):
            delays[0] += float(eff["delay_s"])
    info = dict(ki_a=[ki], kx_n_per_m=[kx], bias_current_a=ib, mass_kg=rotor_mass)
    return ContinuousPlant(A, B, Cy, Ci, Di, delays, ["Z"], info)


# ----------------------------------------------------------------------------------------------
# Exact sampled-data plant: ZOH at the DAC, ADC sampling (with fractional delays), cycle-mean currents
# ----------------------------------------------------------------------------------------------
class SampledPlant:
    def __init__(self, cp: ContinuousPlant, T):
        self.cp, self.T = cp, T
        A, B = cp.A, cp.B
        n, m = B.shape
        self.n, self.m = n, m
        big = np.zeros((n + m, n + m))
        big[:n, :n] = A
        big[:n, n:] = B
        E = sla.expm(big * T)
        self.Ad, self.Bd = E[:n, :n], E[:n, n:]
        # per position output: delay = (md + eps) T, sample x(kT - delay) = E_delta x[k-md-1] + G_delta u[k-md-1]
        self.rows = []
        for j, d in enumerate(cp.delays):
            md = int(math.floor(d / T + 1e-12))
            eps = d / T - md
            delta = (1.0 - eps) * T
            Ed = sla.expm(big * delta)
            c = cp.Cy[j]
            self.rows.append((md, c @ Ed[:n, :n], c @ Ed[:n, n:]))
        # cycle-mean coil current: (1/T) Ci [Int_0^T e^{As} ds x[k] + Int_0^T Int_0^t e^{As} ds dt B u[k]] + Di u[k]
        if np.any(cp.Ci):
            big3 = np.zeros((3 * n, 3 * n))
            big3[:n, :n] = A
            big3[:n, n:2 * n] = np.eye(n)
            big3[n:2 * n, 2 * n:] = np.eye(n)
            E3 = sla.expm(big3 * T)
            G1 = E3[:n, n:2 * n]
            G2 = E3[:n, 2 * n:] @ B
            self.Ci_x = cp.Ci @ G1 / T
            self.Ci_u = cp.Ci @ G2 / T + cp.Di
        else:
            self.Ci_x = np.zeros((m, n))
            self.Ci_u = cp.Di.copy()

    def frf(self, f_hz):
        """Py (p x m) U2 -> V2 and Pi (m x m) U2 -> coil control current, at each frequency."""
        T = self.T
        out_y = np.zeros((len(f_hz), self.m, self.m), complex)
        out_i = np.zeros((len(f_hz), self.m, self.m), complex)
        In = np.eye(self.n)
        for k, f in enumerate(f_hz):
            z = np.exp(2j * math.pi * f * T)
            R = np.linalg.solve(z * In - self.Ad, self.Bd)
            for j, (md, cE, cG) in enumerate(self.rows):
                out_y[k, j, :] = z ** (-(md + 1)) * (cE @ R + cG)
            out_i[k] = self.Ci_x @ R + self.Ci_u
        return out_y, out_i

    def realization(self):
        """Discrete state space incl. the delay registers: s[k+1] = Ad s + Bd u, y = C s (no feedthrough)."""
        n, m = self.n, self.m
        p = len(self.rows)
        extra = sum(1 + md for md, _, _ in self.rows)
        N = n + extra
        Ad = np.zeros((N, N))
        Bd = np.zeros((N, m))
        C = np.zeros((p, N))
        Ad[:n, :n] = self.Ad
        Bd[:n] = self.Bd
        o = n
        for j, (md, cE, cG) in enumerate(self.rows):
            Ad[o, :n] = cE
            Bd[o] = cG
            for l in range(md):
                Ad[o + 1 + l, o + l] = 1.0
            C[j, o + md] = 1.0
            o += 1 + md
        return Ad, Bd, C


# ----------------------------------------------------------------------------------------------
# Digital controller: PID with filtered derivative, optional 2nd-order low-pass and notch, Tustin
# ----------------------------------------------------------------------------------------------
def controller_settings(machine, axis):
    c = machine["controller"]
    if axis == "Z":
        return dict(c["axial"])
    s = dict(c["radial"])
    s.update((c.get("per_axis") or {}).get(axis, {}) or {})
    return s


def controller_tf(s, T):
    """Controller sections (PID with filtered derivative, 2nd-order Butterworth low-pass, notch with
    pre-warped centre), each discretized by Tustin, multiplied: (num, den) in z."""
    kp = float(s["proportional_gain_a_per_m"])
    kI = float(s.get("integral_gain_a_per_m_s", 0.0) or 0.0)
    kd = float(s.get("derivative_gain_a_s_per_m", 0.0) or 0.0)
    wd = 2 * math.pi * float(s.get("derivative_filter_hz", 1e9))
    fs = 1.0 / T
    # PID: kp + kI/s + kd s/(1+s/wd) = [kp s (1+s/wd) + kI (1+s/wd) + kd s^2] / [s (1+s/wd)]
    sections = [(np.polyadd(np.polyadd(kp * np.array([1 / wd, 1, 0]), kI * np.array([1 / wd, 1])),
                            kd * np.array([1, 0, 0])), np.array([1 / wd, 1, 0]))]
    if s.get("lowpass_hz"):
        wl = 2 * math.pi * float(s["lowpass_hz"])
        sections.append((np.array([wl * wl]), np.array([1, math.sqrt(2) * wl, wl * wl])))
    if s.get("notch_hz"):
        fn = float(s["notch_hz"])
        wn = 2 / T * math.tan(math.pi * fn * T)         # pre-warped centre
        zp = float(s.get("notch_width_hz", 0.2 * fn)) / (2 * fn)
        zz = zp * float(s.get("notch_depth", 0.0))
        sections.append((np.array([1, 2 * zz * wn, wn * wn]), np.array([1, 2 * zp * wn, wn * wn])))
    num, den = np.array([1.0]), np.array([1.0])
    for b, a in sections:
        bz, az = ssig.bilinear(b, a, fs)
        num, den = np.polymul(num, bz), np.polymul(den, az)
    return num / den[0], den / den[0]


class Controller:
    def __init__(self, machine, axes, T, comp_delay):
        self.axes, self.T, self.comp_delay = axes, T, comp_delay
        self.tfs = [controller_tf(controller_settings(machine, a), T) for a in axes]

    def frf(self, f_hz):
        z = np.exp(2j * math.pi * np.asarray(f_hz) * self.T)
        out = np.zeros((len(z), len(self.axes), len(self.axes)), complex)
        for k, (n, d) in enumerate(self.tfs):
            out[:, k, k] = np.polyval(n, z) / np.polyval(d, z) * z ** (-self.comp_delay)
        return out

    def realization(self):
        blocks = []
        for n, d in self.tfs:
            A, B, C, D = ssig.tf2ss(n, d)
            # computational delay: D -> through a register
            for _ in range(self.comp_delay):
                k = A.shape[0]
                A2 = np.zeros((k + 1, k + 1))
                A2[:k, :k] = A
                B2 = np.vstack([B, [[0.0]]])
                # y_new[k] = y_old[k-1]: add state holding previous output
                A2[k, :k] = C[0]
                B2[k, 0] = D[0, 0]
                C2 = np.zeros((1, k + 1))
                C2[0, k] = 1.0
                A, B, C, D = A2, B2, C2, np.zeros((1, 1))
            blocks.append((A, B, C, D))
        return lti_blockdiag(blocks)


def closed_loop_radius(sp: SampledPlant, ctrl: Controller):
    Ap, Bp, Cp = sp.realization()
    Ac, Bc, Cc, Dc = ctrl.realization()
    # u = -(Cc xc + Dc y), y = Cp xp
    n1, n2 = Ap.shape[0], Ac.shape[0]
    A = np.zeros((n1 + n2, n1 + n2))
    A[:n1, :n1] = Ap - Bp @ Dc @ Cp
    A[:n1, n1:] = -Bp @ Cc
    A[n1:, :n1] = Bc @ Cp
    A[n1:, n1:] = Ac
    ev = np.linalg.eigvals(A)
    return float(np.max(np.abs(ev)))


# ----------------------------------------------------------------------------------------------
# Stepped sine
# ----------------------------------------------------------------------------------------------
class Experiment:
    def __init__(self, sp, ctrl, settings, rng, noise):
        self.sp, self.ctrl, self.s, self.rng, self.noise = sp, ctrl, settings, rng, noise

    def window_samples(self, f):
        s = self.s
        periods = max(s["measure_periods_min"], math.ceil(s["measure_min_s"] * f))
        return periods, periods / f / self.sp.T

    def respond(self, f, axis_index, amp, Py, Pi, Cz):
        """Closed-loop Fourier coefficients (noisy) of U2, V2, I_upper, I_lower of every axis."""
        m = self.sp.m
        periods, N = self.window_samples(f)
        sig = lambda s_: s_ * math.sqrt(2.0 / N)    # std of re and of im of a white-noise coefficient
        cn = lambda size: self.rng.standard_normal(size) + 1j * self.rng.standard_normal(size)
        ny = cn(m) * sig(self.noise["position_m"])
        nu_ = cn(m) * sig(self.noise["current_a"])
        nl_ = cn(m) * sig(self.noise["current_a"])
        e = np.zeros(m, complex)
        e[axis_index] = -1j * amp                  # excitation A sin(w t)
        L = np.eye(m) + Cz @ Py
        U2 = np.linalg.solve(L, e - Cz @ ny)
        V2 = Py @ U2 + ny
        Ic = Pi @ U2
        return dict(U2=U2, V2=V2, I_upper=Ic + nu_, I_lower=-Ic + nl_), periods

    def run_axis(self, axis_index, freqs):
        s = self.s
        Py, Pi = self.sp.frf(freqs)
        Cz = self.ctrl.frf(freqs)
        rows = []
        amp = s["initial_amplitude_a"]
        for k, f in enumerate(freqs):
            attempts = 0
            while True:
                attempts += 1
                res, periods = self.respond(f, axis_index, amp, Py[k], Pi[k], Cz[k])
                resp = abs(res["V2"][axis_index])
                if s["response_min_m"] <= resp <= s["response_max_m"] or attempts >= s["max_attempts"]:
                    break
                new = amp * (1 + s["growth"]) if resp < s["response_min_m"] else amp * (1 - s["shrink"])
                if new > s["amplitude_max_a"] or new < s["amplitude_min_a"]:
                    clipped = min(max(new, s["amplitude_min_a"]), s["amplitude_max_a"])
                    if abs(clipped - amp) < 1e-12:
                        break          # at the limit already: keep the data (thesis ch. 4.2)
                    amp = clipped
                else:
                    amp = new
            rows.append(dict(step=k, frequency_hz=float(f), amplitude_a=float(amp), attempts=attempts,
                             periods=periods, response_m=float(resp), coeffs=res))
        return rows


def settings_default():
    return dict(response_min_m=20e-6, response_max_m=50e-6, amplitude_min_a=0.05, amplitude_max_a=3.0,
                growth=0.2, shrink=0.2, initial_amplitude_a=0.5, max_attempts=40,
                measure_periods_min=4, measure_min_s=0.2, settle_note="steady state assumed (settled)")


# ----------------------------------------------------------------------------------------------
# Output
# ----------------------------------------------------------------------------------------------
UNIT_FACTOR = {"m": 1.0, "mm": 1e3, "um": 1e6, "A": 1.0, "mA": 1e3}


def channel_list(axes):
    ch = []
    for kind in ("U2", "V2", "I_upper", "I_lower"):
        for a in axes:
            ch.append((f"{kind}_{a}", kind, a))
    return ch


def write_log(path, results, layout, pos_unit, cur_unit, all_channels):
    import pandas as pd
    radial_ch = channel_list(RADIAL)
    z_ch = channel_list(["Z"])
    recs = []
    for axis, rows in results.items():
        if axis == "Z":
            chans = z_ch + (radial_ch if all_channels else [])
            idx_of = {"Z": 0}
        else:
            chans = radial_ch + (z_ch if all_channels else [])
            idx_of = {a: i for i, a in enumerate(RADIAL)}
        for r in rows:
            base = dict(excited_axis=axis, frequency_hz=r["frequency_hz"], step=r["step"],
                        amplitude_a=r["amplitude_a"], attempts=r["attempts"])
            vals = {}
            for name, kind, a in chans:
                fac = UNIT_FACTOR[pos_unit] if kind == "V2" else UNIT_FACTOR[cur_unit]
                if a in idx_of:
                    v = r["coeffs"][kind][idx_of[a]]
                else:
                    v = r["cross"][kind][{"Z": 0}.get(a, RADIAL.index(a) if a in RADIAL else 0)]
                vals[name] = (v * fac, kind)
            if layout == "wide":
                rec = dict(base)
                for name, (v, kind) in vals.items():
                    unit = pos_unit if kind == "V2" else cur_unit
                    suf = "" if unit in ("m", "A") else f"_{unit}"
                    rec[f"{name}_re{suf}"] = v.real
                    rec[f"{name}_im{suf}"] = v.imag
                recs.append(rec)
            else:
                for name, (v, kind) in vals.items():
                    rec = dict(base)
                    rec.update(channel=name, re=v.real, im=v.imag)
                    recs.append(rec)
    df = pd.DataFrame.from_records(recs)
    if layout == "long":
        df = df[["excited_axis", "step", "frequency_hz", "channel", "re", "im", "amplitude_a", "attempts"]]
    df.to_csv(path, index=False, float_format="%.10g")
    return df


# ----------------------------------------------------------------------------------------------
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--machine", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--effects", default="[]", help="JSON list of {name, params...} (or a file path)")
    ap.add_argument("--layout", choices=["wide", "long"], default="wide")
    ap.add_argument("--position-unit", choices=["um", "mm", "m"], default="m")
    ap.add_argument("--current-unit", choices=["A", "mA"], default="A")
    ap.add_argument("--noise-scale", type=float, default=1.0)
    ap.add_argument("--position-noise-m", type=float, default=0.2e-6, help="per-sample sensor noise std")
    ap.add_argument("--current-noise-a", type=float, default=3e-3, help="per-sample coil-current noise std")
    ap.add_argument("--amplitude-max-a", type=float, default=3.0)
    ap.add_argument("--computation-delay-cycles", type=int, default=0,
                    help="controller output one or more cycles late (closed loop only; the logged U2 is the DAC value)")
    ap.add_argument("--fe-subdivision", type=int, default=1)
    ap.add_argument("--all-channels", action="store_true", help="every step carries all 20 channels")
    ap.add_argument("--axes", default="DX,DY,NX,NY,Z")
    args = ap.parse_args(argv)

    with open(args.machine) as fh:
        machine = yaml.safe_load(fh)
    eff_src = args.effects
    if os.path.exists(eff_src):
        with open(eff_src) as fh:
            eff_src = fh.read()
    effects = json.loads(eff_src)
    if isinstance(effects, dict):
        effects = [effects]
    norm = []
    for e in effects:
        e = dict(e)
        if "parameters" in e:                       # also accept {name, parameters: {...}}
            p = e.pop("parameters")
            e.update(p)
        if e["name"] not in KNOWN_EFFECTS:
            raise SystemExit(f"unknown effect {e['name']!r}; known: {sorted(KNOWN_EFFECTS)}")
        norm.append(e)
    effects = norm
    machine_effects = machine.get("effects") or []
    if machine_effects:
        # the machine file's own effects are part of the machine as built
        for e in machine_effects:
            d = {"name": e["name"]}
            d.update(e.get("parameters") or {})
            effects.insert(0, d)

    T = float(machine.get("controller", {}).get("sample_time_s", 5e-5))
    rng = np.random.default_rng(args.seed)
    noise = dict(position_m=args.position_noise_m * args.noise_scale,
                 current_a=args.current_noise_a * args.noise_scale)
    st = settings_default()
    st["amplitude_max_a"] = args.amplitude_max_a

    rcp, rotor = radial_plant(machine, effects, args.fe_subdivision)
    acp = axial_plant(machine, effects, rotor.mass)
    rsp, asp = SampledPlant(rcp, T), SampledPlant(acp, T)
    rctrl = Controller(machine, RADIAL, T, args.computation_delay_cycles)
    actrl = Controller(machine, ["Z"], T, args.computation_delay_cycles)
    rho_r = closed_loop_radius(rsp, rctrl)
    rho_a = closed_loop_radius(asp, actrl)
    if rho_r >= 1 or rho_a >= 1:
        print(f"warning: closed loop unstable (spectral radius radial {rho_r:.6f}, axial {rho_a:.6f})",
              file=sys.stderr)
    # sensitivity peaks of the sampled loop (output sensitivity seen at U2: (I + C P)^-1, diagonal)
    fs_dense = np.linspace(1.0, 0.5 / T * 0.999, 1500)
    Py, _ = rsp.frf(fs_dense)
    Cz = rctrl.frf(fs_dense)
    Sd = np.array([np.linalg.inv(np.eye(4) + Cz[k] @ Py[k]) for k in range(len(fs_dense))])
    peaks = {a: float(20 * np.log10(np.max(np.abs(Sd[:, i, i])))) for i, a in enumerate(RADIAL)}
    Pyz, _ = asp.frf(fs_dense)
    Czz = actrl.frf(fs_dense)
    peaks["Z"] = float(20 * np.log10(np.max(np.abs(1 / (1 + Czz[:, 0, 0] * Pyz[:, 0, 0])))))

    grid = machine["frequency_grid"]
    fr = np.linspace(grid["radial"]["start_hz"], grid["radial"]["stop_hz"], int(grid["radial"]["points"]))
    fa = np.linspace(grid["axial"]["start_hz"], grid["axial"]["stop_hz"], int(grid["axial"]["points"]))
    results = {}
    rexp = Experiment(rsp, rctrl, st, rng, noise)
    aexp = Experiment(asp, actrl, st, rng, noise)
    axes = args.axes.split(",")
    for a in axes:
        if a == "Z":
            results["Z"] = aexp.run_axis(0, fa)
        else:
            results[a] = rexp.run_axis(RADIAL.index(a), fr)
    if args.all_channels:
        # the other bearing's channels: its closed loop driven only by its own noise (no coupling)
        for a, rows in results.items():
            other_sp, other_ctrl = (rsp, rctrl) if a == "Z" else (asp, actrl)
            oexp = Experiment(other_sp, other_ctrl, st, rng, noise)
            freqs = np.array([r["frequency_hz"] for r in rows])
            Py_o, Pi_o = other_sp.frf(freqs)
            Cz_o = other_ctrl.frf(freqs)
            for k, r in enumerate(rows):
                res, _ = oexp.respond(r["frequency_hz"], 0, 0.0, Py_o[k], Pi_o[k], Cz_o[k])
                r["cross"] = res

    os.makedirs(args.out, exist_ok=True)
    df = write_log(os.path.join(args.out, "identification.csv"), results, args.layout,
                   args.position_unit, args.current_unit, args.all_channels)
    truth = dict(
        generator="foreign_rig.py (independent of ambid)",
        machine_file=os.path.abspath(args.machine), machine=machine.get("name"),
        seed=args.seed, effects=[e for e in effects if e not in machine_effects],
        effects_applied=effects,
        layout=args.layout, position_unit=args.position_unit, current_unit=args.current_unit,
        amplitude_column_unit="A",
        noise=dict(position_std_per_sample_m=noise["position_m"], current_std_per_sample_a=noise["current_a"],
                   noise_scale=args.noise_scale,
                   model="white, added at the ADC (position) and per coil measurement (current); "
                         "coefficient noise std per re/im = sigma*sqrt(2/N), N samples in the window; "
                         "position noise fed back through the sampled loop into U2 and V2"),
        sample_time_s=T, computation_delay_cycles=args.computation_delay_cycles,
        excitation="E_u = A sin(2 pi f t) added to the controller output; Fourier coefficient "
                   "X = (2/N) sum x[n] exp(-j w n T), so the excitation's coefficient is -jA",
        conventions=dict(
            U2="digital control-current command after the excitation is added (= DAC input, held by ZOH) [A]",
            V2="ADC-sampled sensor position (rotor relative to housing, after sensor dynamics/delay) [m]",
            I_upper="bias + control current, measured: mean coil current over the controller cycle "
                    "of the command (ideal amplifier: exactly bias + U2) + noise",
            I_lower="bias - control current, measured likewise",
            sign="force F = ki i + kx x with kx > 0 (negative stiffness); controller u = -C(z) y",
            delay_effect="applied to position channels only (sensor/ADC path), not to coil currents",
            element_stiffness="bending stiffness EI of tagged elements (incl. counted sleeve part) scaled, G kept",
            eddy_current="first-order lag between coil current and force (ki path only; kx unaffected)",
            gyroscopic="spin about +z (x -> y), forward whirl rises with speed",
            foundation_mode="one housing mass per bearing and plane on a spring/damper to ground; "
                            "force reacts on it; sensor reads rotor minus housing",
            housing_coupled="one frame per plane (x, y) carrying both housings rigidly",
            xy_anisotropy="ki and kx of DY and NY multiplied by factor",
            cross_coupling="input: force current f = (I + c J) i; output: y = (I + c J) x; J swaps x<->y of a bearing",
            controller="PID kp + ki/s + kd s/(1+s/wd), x 2nd-order Butterworth low-pass, x notch "
                       "(depth = zero/pole damping ratio, width = 2 zeta_p f_n, centre pre-warped); Tustin",
            steps_channels="radial steps carry the 16 radial channels, Z steps the 4 Z channels"
                           + (" (plus the other bearing's: --all-channels)" if args.all_channels else ""),
        ),
        stepped_sine=st,
        stepped_sine_window="periods = max(measure_periods_min, ceil(measure_min_s * f)), steady state",
        radial=rcp.info, axial=acp.info,
        closed_loop=dict(spectral_radius_radial=rho_r, spectral_radius_axial=rho_a,
                         sensitivity_peak_db=peaks),
        fe_subdivision=args.fe_subdivision,
        n_rows=int(len(df)),
        steps={a: len(r) for a, r in results.items()},
        amplitude_range_a={a: [min(x["amplitude_a"] for x in r), max(x["amplitude_a"] for x in r)]
                           for a, r in results.items()},
    )
    with open(os.path.join(args.out, "truth.json"), "w") as fh:
        json.dump(truth, fh, indent=1, default=float)
    print(f"wrote {args.out}/identification.csv ({len(df)} rows), truth.json; "
          f"closed loop radius radial {rho_r:.5f} axial {rho_a:.5f}; "
          f"sensitivity peaks dB " + ", ".join(f"{k} {v:.2f}" for k, v in peaks.items()))


if __name__ == "__main__":
    main()
