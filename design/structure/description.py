"""The design as Python values: frozen dataclasses of the truss (materials, sections,
connectors, nodes, members), its joints, sensors and disturbances, model updating, control and
safety settings (paper Sections 2–3, 5), as `spec.load_design` returns them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from smartjoint.common import friction_registry
from smartjoint.common.errors import DesignError
from smartjoint.design.structure.uncertainty import Uncertainty

DOF_NAMES = ("ux", "uy", "uz", "rx", "ry", "rz")
JOINT_TYPES = ("A", "B")
SENSOR_QUANTITIES = ("displacement", "velocity")


@dataclass(frozen=True)
class Material:
    name: str
    youngs_modulus: float  # E [Pa]
    shear_modulus: float  # G [Pa]
    density: float  # ρ [kg/m³]


@dataclass(frozen=True)
class TubeSection:
    """Thin- or thick-walled circular tube."""

    name: str
    material: str
    outer_diameter: float  # [m]
    wall_thickness: float  # [m]

    @property
    def area(self) -> float:
        inner = self.outer_diameter - 2.0 * self.wall_thickness
        return math.pi / 4.0 * (self.outer_diameter**2 - inner**2)

    @property
    def second_moment(self) -> float:
        """I_y = I_z [m⁴]."""
        inner = self.outer_diameter - 2.0 * self.wall_thickness
        return math.pi / 64.0 * (self.outer_diameter**4 - inner**4)

    @property
    def polar_moment(self) -> float:
        """I_p = J = 2I for a circular tube [m⁴]."""
        return 2.0 * self.second_moment


@dataclass(frozen=True)
class Connector:
    """Screw end connector between a node and a tube: its own beam element.

    Its stiffnesses are given directly (they are what model updating identifies); its mass is
    spread along its length, with the rotary inertia of a solid cylinder of ``diameter``.
    """

    name: str
    length: float  # [m]
    mass: float  # [kg]
    diameter: float  # [m]
    axial_stiffness: float  # EA [N]
    bending_stiffness: float  # EI [N·m²]
    torsional_stiffness: float  # GJ [N·m²]


@dataclass(frozen=True)
class NodeType:
    """A perfectly rigid truss node (Meroform ball) with lumped mass and inertia."""

    name: str
    mass: float  # [kg]
    seat_radius: float  # centre to connector seat [m]
    inertia: float  # about any axis through the centre [kg·m²]


@dataclass(frozen=True)
class Node:
    name: str
    position: tuple[float, float, float]
    type: str | None  # None: a plain point without mass or offset


@dataclass(frozen=True)
class Member:
    name: str
    start: str
    end: str
    section: str
    connector: str | None
    elements: int  # tube elements


@dataclass(frozen=True)
class PointMass:
    node: str
    mass: float
    inertia: float


@dataclass(frozen=True)
class Support:
    node: str
    dofs: tuple[str, ...]


@dataclass(frozen=True)
class JointFriction:
    """A joint's friction parameters per unit normal force and where they came from.

    ``model`` names the friction model of ``common/friction_registry.py`` (LuGre, Eq. 1–2: the
    columns of Table 1); ``parameters`` holds its parameters as (key, value) pairs in the
    model's order — per radian for a type B joint, which also has its contact radius r [m].
    ``source`` names the design file and key or the parameter file; ``sha256`` is that file's
    hash (empty when given inline).
    """

    joint_type: str  # "A" | "B"
    parameters: tuple[tuple[str, float], ...]
    radius: float | None
    source: str
    sha256: str = ""
    model: str = friction_registry.DEFAULT

    def values(self) -> dict[str, float]:
        """The model's parameters by key, without the radius."""
        return dict(self.parameters)


@dataclass(frozen=True)
class Joint:
    """A friction joint at one end of a member (paper Fig. 3).

    Type A releases the axial slip of the member end against the node; type B releases the
    rotation of the member end about ``axis`` (perpendicular to the member). ``friction``: the
    joint's own LuGre parameters; None takes those of its type (``Design.friction``).
    """

    name: str
    member: str
    end: str  # "start" | "end"
    type: str  # "A" | "B"
    axis: tuple[float, float, float] | None
    friction: JointFriction | None = None


@dataclass(frozen=True)
class Sensor:
    """One measured output y (Eq. 10): a node's displacement or velocity along a direction."""

    name: str
    node: str
    direction: tuple[float, ...]  # 6-vector over DOF_NAMES
    quantity: str


@dataclass(frozen=True)
class Disturbance:
    """One disturbance input w (Eq. 5): a force/moment at a node along a direction."""

    name: str
    node: str
    direction: tuple[float, ...]  # 6-vector over DOF_NAMES


@dataclass(frozen=True)
class MeasuredDof:
    """One DOF of the modal survey (an accelerometer channel): a node's motion along a direction."""

    node: str
    direction: tuple[float, ...]  # 6-vector over DOF_NAMES, as for a Sensor


@dataclass(frozen=True)
class MeasuredMode:
    """One mode of the modal survey (EMA, paper Fig. 7).

    ``shape`` holds the real-valued EMA mode shape, one component per DOF of
    ``Updating.measured_dofs`` (any scaling and sign: the MAC does not see them); None without one.
    """

    mode: int  # 1-based index in the ascending FE spectrum
    frequency_hz: float
    mac: float | None
    shape: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Updating:
    """The [updating] section: parameters and bounds, the measured modes, optionally their shapes
    at ``measured_dofs`` and the weight of a MAC term in the objective (0: frequencies only)."""

    parameters: tuple[str, ...]  # e.g. "connectors.m12.axial_stiffness"
    measured: tuple[MeasuredMode, ...]
    max_factors: tuple[float, ...]  # per parameter: bounds initial/max_factor .. initial·max_factor
    measured_dofs: tuple[MeasuredDof, ...] = ()
    mac_weight: float = 0.0

    @property
    def has_shapes(self) -> bool:
        """Whether the measured modes carry EMA shapes (then modes are paired by MAC)."""
        return bool(self.measured_dofs)


@dataclass(frozen=True)
class Placement:
    """``[placement]``: the type A joints ``smartjoint run`` places on a design without joints
    (paper Section 6): ``count`` joints at the end connectors with the largest axial modal
    strain energy of the ``modes`` (1-based)."""

    modes: tuple[int, ...]
    count: int


@dataclass(frozen=True)
class Control:
    """Controller design inputs (paper Section 5; ``[control]``, all optional with defaults).

    Limits F_N^min..F_N^max per joint (a number applies to every joint), the controller sample
    time Δt, the reduced model the controllers are designed on (Section 4: ``modes`` of the
    first ``considered`` plus ``krylov`` correction vectors per joint), LQR weights
    (xᵀQx + uᵀRu with Q = state_weight·I — xᵀx is the energy of Eq. 32 — and R =
    control_weight·I), Kalman noise intensities (process: on the disturbance inputs w, N²;
    measurement: per sensor, m²), each law's settings (``law_settings``: the registry's
    ``Setting``s the file gives, e.g. the laws' boundary layers), the piezo calibration used for the
    control power (F_N = force_per_volt·V + preload, capacitance per stack) and the study
    length t_e of Eq. 32."""

    joints: tuple[str, ...] | None = None  # controlled joints; None: all
    sample_time: float = 1e-3
    normal_force_min: tuple[float, ...] | float = 10.0
    normal_force_max: tuple[float, ...] | float = 400.0
    considered_modes: int = 100
    modes: int = 9
    krylov: int = 1
    state_weight: float = 1.0
    control_weight: float = 1e-6
    process_noise: float = 1e4
    measurement_noise: float = 1e-10
    # Each law's settings the file gives ([control] <law>_<key>, common.law_registry): law → key → value
    law_settings: dict[str, dict[str, tuple[float, ...] | float]] = field(default_factory=dict)
    piezo_capacitance: float = 1.8e-6
    piezo_force_per_volt: float = 8.0
    piezo_preload: float = 0.0
    study_duration: float = 4.0
    reduction_normal_force: tuple[float, ...] | float | None = None
    pulse_amplitude: float = 200.0  # N: the study's tip pulse (Section 4.3)
    # The keys of PAPER_VALUES the file left out: those settings are the paper's, and a stage says so.
    paper_values: tuple[str, ...] = ()


# The [control] keys whose defaults are the paper's demonstrator (Section 6): a design that leaves
# them out runs with the paper's values, which the report names (they are not the user's joints').
PAPER_VALUES = ("sample_time", "normal_force_min", "normal_force_max", "study_duration", "pulse_amplitude")


@dataclass(frozen=True)
class Bus:
    """One CAN FD bus of ``[network]``: its name, nominal and data bit rates [bit/s] and the
    worst-case load it may carry (a fraction)."""

    name: str
    bitrate: int = 1_000_000
    data_bitrate: int = 5_000_000
    limit: float = 0.70


@dataclass(frozen=True)
class Network:
    """The controller's network (``[network]``, optional; docs/design-file.md): the CAN FD buses
    in the order the plan fills them (``design.network.plan``), where the SISO law runs
    (``siso``: "central", the default — the bundled bench measures the central chain — or
    "local" on the joint nodes, docs/safety.md) and the samples per heartbeat and node status
    frame of local mode (``supervision_cycles``)."""

    buses: tuple[Bus, ...] = (Bus("can0"),)
    siso: str = "central"
    supervision_cycles: int = 10


@dataclass(frozen=True)
class Xcp:
    """The firmware's XCP slave on CAN FD (``[xcp]``, optional; docs/xcp.md): measurement by DAQ
    at the controller's sample and calibration of the laws' tunables.

    ``bus``: the bus of ``[network]`` XCP shares (None: a bus of its own, ``xcp``);
    ``master_id``/``slave_id``: the CAN identifiers master → slave (commands) and slave → master
    (answers and DAQ), above every frame of the control protocol so XCP never delays it;
    ``key``: the 128-bit key of the seed & key algorithm as 32 hex digits (None: derived from
    the artefact's hash, so every artefact has its own); ``daq_entries``: the ODT entries the
    slave holds; ``calibration_decades``: a tunable that is no normal force may be calibrated
    within this many decades of the design's value either side."""

    master_id: int = 0x7F0
    slave_id: int = 0x7F1
    key: str | None = None
    bus: str | None = None
    daq_entries: int = 32
    calibration_decades: float = 2.0


@dataclass(frozen=True)
class Safety:
    """The safe state and the plausibility ranges of the firmware (``[safety]``, all optional;
    docs/safety.md says why each default is what it is).

    ``safe_normal_force``: the normal force every joint gets while the controller cannot act —
    "max" (F_N^max, the default: locked joints keep the truss as stiff and shape-accurate as
    its rigid design, and a constant F_N can never destabilise it), "min", or newtons (a number
    or one per controlled joint, within [F_N^min, F_N^max]). The same force holds in the
    controllers, the CAN layer, the amplifiers (power-up, silence, bus-off) and the reports.

    Plausibility: a measured value beyond its range is not physics but a broken sensor or
    frame. ``sliding_velocity_limit`` |v| [m/s]; ``friction_coefficient_limit`` |u_R| ≤ this ×
    the largest plausible F_N; ``normal_force_margin`` the measured F_N within [−m, 1 + m]·F_N^max;
    ``displacement_limit`` [m] / ``velocity_limit`` [m/s] for the sensors by quantity
    (displacement default: 5 % of the truss's largest extent); ``amplifier_temperature_limit``
    [°C], ``amplifier_current_limit`` [A]; ``tracking_tolerance`` [V] between the setpoint and
    the amplifier's monitor voltage; ``actuation_tolerance`` (a fraction of F_N^max) by which the
    measured F_N may fall short of the least of the last three commands before the joint counts as
    not following (docs/safety.md, the actuation check).

    Timing, the same in the firmware and the amplifiers: an input whose newest frame is
    ``timeout_cycles`` controller cycles old is missing (2: a frame may come up to one cycle
    late), and the safe state ends after ``recovery_cycles`` fault-free cycles in a row."""

    safe_normal_force: tuple[float, ...] | float | str = "max"
    sliding_velocity_limit: float = 1.0
    friction_coefficient_limit: float = 1.5
    normal_force_margin: float = 0.1
    displacement_limit: float | None = None  # None: 5 % of the largest extent of the nodes
    velocity_limit: float = 2.0
    amplifier_temperature_limit: float = 85.0
    amplifier_current_limit: float = 2.5
    tracking_tolerance: float = 3.0
    actuation_tolerance: float = 0.1
    timeout_cycles: int = 2
    recovery_cycles: int = 3


@dataclass(frozen=True)
class Design:
    name: str
    description: str
    materials: dict[str, Material]
    sections: dict[str, TubeSection]
    connectors: dict[str, Connector]
    node_types: dict[str, NodeType]
    nodes: dict[str, Node]
    members: dict[str, Member]
    point_masses: tuple[PointMass, ...]
    supports: tuple[Support, ...]
    joints: tuple[Joint, ...]
    sensors: tuple[Sensor, ...]
    disturbances: tuple[Disturbance, ...]
    modal_damping: float
    updating: Updating | None
    control: Control = field(default_factory=Control)
    safety: Safety = field(default_factory=Safety)
    source: str = "<memory>"
    sha256: str = ""
    truss: dict[str, Any] = field(default_factory=dict)
    friction: dict[str, JointFriction] = field(default_factory=dict)  # by joint type ([friction.A])
    friction_records: tuple[str, ...] = ()  # rig records `run` identifies ([friction] records)
    placement: Placement | None = None  # joints `run` places on a design without [[joints]]
    uncertainty: Uncertainty = field(default_factory=Uncertainty)  # [uncertainty]: the physical spread
    network: Network = field(default_factory=Network)  # [network]: buses, local or central SISO
    xcp: Xcp = field(default_factory=Xcp)  # [xcp]: the XCP slave's identifiers, key and DAQ memory

    def joint_friction(self, joint: Joint) -> JointFriction | None:
        """The joint's LuGre parameters: its own, else its type's; None when the design has none."""
        return joint.friction if joint.friction is not None else self.friction.get(joint.type)

    def with_friction(self, friction: JointFriction) -> Design:
        """A copy whose joints of ``friction.joint_type`` take ``friction`` (identified
        parameters replace what the design file said, the joints' own included)."""
        joints = tuple(
            dataclasses.replace(j, friction=None) if j.type == friction.joint_type else j for j in self.joints
        )
        return dataclasses.replace(self, joints=joints, friction={**self.friction, friction.joint_type: friction})

    def parameter(self, key: str) -> float:
        """Value of an updatable parameter ``table.name.field`` (see :data:`UPDATABLE`)."""
        table, name, attribute = split_parameter(key)
        return float(getattr(getattr(self, table)[name], attribute))

    def with_parameters(self, values: dict[str, float]) -> Design:
        """A copy with updatable parameters replaced (used by model updating)."""
        tables = {t: dict(getattr(self, t)) for t in ("materials", "connectors")}
        for key, value in values.items():
            table, name, attribute = split_parameter(key)
            tables[table][name] = dataclasses.replace(tables[table][name], **{attribute: float(value)})
        return dataclasses.replace(self, materials=tables["materials"], connectors=tables["connectors"])


UPDATABLE = {
    "materials": ("youngs_modulus", "shear_modulus"),
    "connectors": ("axial_stiffness", "bending_stiffness", "torsional_stiffness"),
}


def split_parameter(key: str) -> tuple[str, str, str]:
    """``"materials.steel.youngs_modulus"`` → (table, name, field) of an updatable parameter.

    Parameters
    ----------
    key : str
        ``table.name.field`` with table and field from :data:`UPDATABLE`.

    Returns
    -------
    tuple of str
        (table, name, field).

    Raises
    ------
    DesignError
        For a key that is not of that form.
    """
    parts = key.split(".")
    if len(parts) != 3 or parts[0] not in UPDATABLE or parts[2] not in UPDATABLE[parts[0]]:
        allowed = ", ".join(f"{t}.<name>.{a}" for t, attrs in UPDATABLE.items() for a in attrs)
        raise DesignError("updating.parameters", key, f"allowed: {allowed}")
    return parts[0], parts[1], parts[2]


__all__ = [
    "Connector",
    "Control",
    "DOF_NAMES",
    "Design",
    "Disturbance",
    "JOINT_TYPES",
    "Joint",
    "Material",
    "MeasuredDof",
    "MeasuredMode",
    "Member",
    "Node",
    "NodeType",
    "PointMass",
    "SENSOR_QUANTITIES",
    "Safety",
    "Sensor",
    "Support",
    "TubeSection",
    "UPDATABLE",
    "Updating",
    "Xcp",
    "split_parameter",
]
