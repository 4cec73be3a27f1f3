"""Export of an ambid rotor to ROSS (ross-rotordynamics), for cross-checks.

ROSS is an optional, heavy dependency (``make crosscheck`` builds its own
environment); it is imported only when this function is called.
"""

__all__ = ["to_ross_rotor"]


def to_ross_rotor(rotor, bearings=()):
    """The same rotor as a ``ross.Rotor``: Timoshenko elements with Cowper's shear coefficient.

    Parameters
    ----------
    rotor : ambid.rotor.Rotor
        Must have no sleeves (ROSS has no equivalent).
    bearings : sequence of (node, stiffness_n_per_m) or (node, kxx_n_per_m, kyy_n_per_m)
        Linear undamped bearings (negative for an AMB's position stiffness);
        none gives a free-free rotor.

    Notes
    -----
    Materials pass E, G and rho, so ROSS derives the same Poisson ratio
    ``E / (2 G) - 1`` that ambid uses in the shear coefficient.  One ROSS
    material per distinct (E, G, rho): an updated rotor's scaled elements
    (`ambid.rotor.Rotor.with_youngs_modulus_scaled`) keep their material's
    name with another modulus.
    """
    import ross

    if rotor.sleeves:
        raise ValueError("ROSS has no sleeves; export a rotor without them")
    materials = {}
    elements = []
    for element in rotor.elements:
        m = element.material
        key = (m.name, float(m.density_kg_m3), float(m.youngs_modulus_pa), float(m.shear_modulus))
        if key not in materials:
            materials[key] = ross.Material(
                name=f"ambid_{m.name}_{len(materials)}", rho=key[1], E=key[2], G_s=key[3]
            )
        elements.append(
            ross.ShaftElement(
                L=element.length_m,
                idl=element.inner_diameter_m,
                odl=element.outer_diameter_m,
                material=materials[key],
                shear_effects=True,
                rotary_inertia=True,
                gyroscopic=True,
                shear_method_calc="cowper",
            )
        )
    disks = [
        ross.DiskElement(n=d.node, m=d.mass_kg, Id=d.transverse_inertia_kg_m2, Ip=d.polar_inertia_kg_m2)
        for d in rotor.disks
    ]
    bearing_elements = [
        ross.BearingElement(n=int(node), kxx=float(k[0]), kyy=float(k[-1]), cxx=0.0) for node, *k in bearings
    ]
    return ross.Rotor(elements, disks, bearing_elements)
