"""Shared helpers: small design dictionaries built in code (validated by parse_design)."""

from __future__ import annotations

import copy

import pytest

ALUMINIUM = {"youngs_modulus": 70.0e9, "shear_modulus": 26.0e9, "density": 2700.0}
TUBE = {"material": "aluminium", "outer_diameter": 0.022, "wall_thickness": 0.0015}


def beam_design(length: float = 2.0, elements: int = 10, clamp: bool = True) -> dict:
    """A single straight tube from A (clamped) to B along x, no connectors, massless nodes."""
    design = {
        "name": "beam",
        "materials": {"aluminium": dict(ALUMINIUM)},
        "sections": {"tube": dict(TUBE)},
        "nodes": [{"name": "A", "position": [0.0, 0.0, 0.0]}, {"name": "B", "position": [length, 0.0, 0.0]}],
        "members": [{"name": "M", "start": "A", "end": "B", "section": "tube", "elements": elements}],
    }
    if clamp:
        design["supports"] = [{"node": "A", "dofs": "all"}]
    return design


def small_truss() -> dict:
    """A 2-bay mast with connectors, rigid nodes, tip node, sensors and disturbances."""
    return {
        "name": "small",
        "materials": {"aluminium": dict(ALUMINIUM)},
        "sections": {"tube": dict(TUBE)},
        "connectors": {"c": {"length": 0.05, "mass": 0.06, "diameter": 0.022, "axial_stiffness": 5e6,
                             "bending_stiffness": 800.0, "torsional_stiffness": 600.0}},
        "node_types": {"ball": {"mass": 0.25, "seat_radius": 0.023}},
        "mesh": {"tube_elements": 2},
        "truss": {"bays": 2, "bay_length": 1.0, "width": 1.0, "node_type": "ball", "section": "tube",
                  "connector": "c", "tip_node": "cross"},
        "point_masses": [{"node": "TIP", "mass": 0.5}],
        "sensors": [{"name": "tip_y", "node": "TIP", "direction": "uy"},
                    {"name": "tip_vz", "node": "TIP", "direction": "uz", "quantity": "velocity"}],
        "disturbances": [{"name": "fy", "node": "TIP", "direction": "uy"}],
        "joints": [{"name": "JA", "member": "L2_0", "end": "end", "type": "A"},
                   {"name": "JB", "member": "D1_1", "end": "start", "type": "B", "axis": [0.0, 1.0, 0.0]}],
    }


@pytest.fixture
def truss_dict():
    return copy.deepcopy(small_truss())


@pytest.fixture(scope="session")
def three_type_a():
    """The paper's configuration (Fig. 11), updated to the EMA, and its 24-state design model."""
    from smartjoint.design import load_design, spec, study, updated_design

    design, _ = updated_design(load_design(spec.REFERENCE_DESIGN.parent / "three_type_a.toml"))
    return design, study.design_model(design, lambda message: None)
