"""Neutral model format: everything another FE code needs to rebuild the same truss model.

The format (``smartjoint-model/1``) is documented in ``docs/model-format.md``. It lists the
points, the beam elements with their section properties and orientation, the rigid links
of the node constraints (Eq. 4) with the DOF each friction joint releases, the lumped
masses and the supports. It is plain data: no smartjoint objects, SI units throughout.
"""

from __future__ import annotations

from smartjoint.design.structure.fem import FEModel

SCHEMA = "smartjoint-model/1"


def export_model(model: FEModel) -> dict:
    """The model as a JSON-ready dictionary (see ``docs/model-format.md``).

    Parameters
    ----------
    model : FEModel
        The FE model.

    Returns
    -------
    dict
        Points, elements with their properties and frames, rigid links with their releases,
        lumped masses and the DOF labels, under the schema ``SCHEMA``.
    """
    design = model.design
    properties = model.element_properties
    elements = []
    for e, (a, b) in enumerate(model.element_points):
        EA, EIy, EIz, GJ, rhoA, rhoIp = (float(v) for v in properties[e])
        elements.append(
            {
                "points": [int(a), int(b)],
                "member": model.element_member[e],
                "kind": model.element_kind[e],
                "local_y": [float(v) for v in model.element_rotation[e, 1]],
                "EA": EA,
                "EIy": EIy,
                "EIz": EIz,
                "GJ": GJ,
                "mass_per_length": rhoA,
                "polar_inertia_per_length": rhoIp,
            }
        )
    return {
        "schema": SCHEMA,
        "design": {"name": design.name, "source": design.source, "sha256": design.sha256},
        "units": {"length": "m", "mass": "kg", "force": "N", "angle": "rad"},
        "dof_order": ["ux", "uy", "uz", "rx", "ry", "rz"],
        "joints": "released" if model.joints_released else "locked",
        "parameters": dict(sorted(model.parameters.items())),
        "modal_damping": design.modal_damping,
        "points": [{"name": n, "position": [float(v) for v in p]} for n, p in zip(model.point_names, model.points)],
        "elements": elements,
        "rigid_links": model.rigid_links,
        "lumped_masses": model.lumped_masses,
        "supports": [{"node": s.node, "dofs": list(s.dofs)} for s in design.supports],
        "sensors": [
            {"name": s.name, "node": s.node, "direction": list(s.direction), "quantity": s.quantity}
            for s in design.sensors
        ],
        "disturbances": [{"name": d.name, "node": d.node, "direction": list(d.direction)} for d in design.disturbances],
    }


__all__ = ["export_model", "SCHEMA"]
