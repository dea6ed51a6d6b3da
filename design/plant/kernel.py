"""The seam between the loop driver and a simulation scheme: the run description, the kernel
protocol every scheme's kernels implement, the state and recording arrays they share with numpy,
and the cffi module of ``plant_kernel.c`` (declarations read from ``plant_kernel.h``).

A scheme (``schemes.py``) turns a :class:`PlantRun` into a :class:`Kernel`; the loop driver
(``loop.simulate``) then only calls the kernel's methods, whatever sits behind them (numpy, C,
or an external plant such as an FMU or a processor-in-the-loop target).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from smartjoint.design.plant.interface import Controller, Measurements
from smartjoint.design.structure.modal import ModalModel


@dataclass(frozen=True)
class PlantRun:
    """What a scheme needs to check a run and build its kernel (the arguments of ``simulate``)."""

    model: ModalModel
    joints: list
    controller: Controller
    duration: float
    step: float
    initial_state: np.ndarray | None
    record_every: int
    backend: str
    energy_books: bool
    stick_step: float | None
    sample_steps: np.ndarray | None = None  # the plant step of each controller sample; None: every ratio-th

    @property
    def steps(self) -> int:
        """The number of plant steps of the run."""
        return int(round(self.duration / self.step))

    @property
    def rows(self) -> int:
        """The number of recorded rows."""
        return self.steps // self.record_every + 1


class Recorder:
    """The recorded rows of a run: per joint v, u_R, F_N, φ; sensors, e = ½xᵀx, the three works."""

    def __init__(self, rows: int, joints: int, sensors: int):
        self.v, self.u, self.fn, self.phi = (np.zeros((rows, joints)) for _ in range(4))
        self.sensors = np.zeros((rows, sensors))
        self.energy = np.zeros(rows)
        self.works = np.zeros((rows, 3))

    def fields(self) -> dict[str, np.ndarray]:
        """The arrays in the order of the C kernels' ``sj_record`` (``plant_kernel.h``)."""
        names = ("v", "u", "fn", "phi", "sensors", "energy", "works")
        return {name: getattr(self, name) for name in names}


class State:
    """The plant state a kernel advances in place: x (2, n) = [η̇; ωη], q = E·u_R (n), and per joint
    v, φ, u_R, F_N; ``works`` W_in, W_joints, W_damping. ``joint_input_t``: Eᵀ (l, n), C-ordered."""

    def __init__(self, joint_input_t: np.ndarray, initial_state):
        l, n = joint_input_t.shape
        self.x = (
            np.zeros((2, n))
            if initial_state is None
            else np.ascontiguousarray(np.array(initial_state, dtype=float).reshape(n, 2).T)
        )
        self.q = np.zeros(n)
        self.v = joint_input_t @ self.x[0]
        self.phi, self.u, self.fn = np.zeros(l), np.zeros(l), np.zeros(l)
        self.works = np.zeros(3)

    def measure(self, time: float, velocity_output: np.ndarray, displacement_output: np.ndarray) -> Measurements:
        """The controller's view of this state (sensors y = V·η̇ + D·ωη)."""
        sensors = velocity_output @ self.x[0] + displacement_output @ self.x[1]
        return Measurements(time, sensors, self.v.copy(), self.u.copy(), self.fn.copy())


class Kernel(Protocol):
    """One run of a scheme, advanced by the loop driver.

    The driver calls ``start(w0)`` once, then per controller sample ``measure(t)``, the
    controller, ``set_normal_force(commands)`` (held until the next sample) and
    ``run(w, steps, k0, record_every)``, and at the end ``record_row`` of the last row.
    ``recorder`` holds the recorded rows; ``name`` says what computes ("c", "python", …).
    """

    name: str
    recorder: Recorder

    def start(self, w0: np.ndarray) -> None: ...

    def measure(self, time: float) -> Measurements: ...

    def set_normal_force(self, normal_force: np.ndarray) -> None: ...

    def run(self, w: np.ndarray, steps: int, k0: int, record_every: int) -> None: ...

    def record_row(self, row: int) -> None: ...


class Scheme(Protocol):
    """A simulation scheme as the registry (``schemes.py``) lists it: a module (or any object)
    with these names, looked up at every run (so a test may replace one).

    ``check(run)`` raises a named ``ModelError`` for a run the scheme cannot do; ``kernel(run)``
    builds the :class:`Kernel`. ``FRICTION``: the LuGre joints are part of the plant (the
    controller commands normal forces >= 0, one LuGre law per joint); False: a frictionless
    plant driven by the controller's joint forces (no laws). ``COMPACT_DISTURBANCE``: the
    kernel takes the rows of w after the disturbance's support as zero, so the driver leaves
    them out.
    """

    FRICTION: bool
    COMPACT_DISTURBANCE: bool

    def check(self, run: PlantRun) -> None:
        """Raise a named ``ModelError`` where the scheme cannot do the run.

        Parameters
        ----------
        run : PlantRun
            The run as ``loop.simulate`` received it, its general conditions checked.
        """

    def kernel(self, run: PlantRun) -> Kernel:
        """The kernel of the run.

        Parameters
        ----------
        run : PlantRun
            The run as ``loop.simulate`` received it, checked by ``check``.

        Returns
        -------
        Kernel
            A new kernel at the run's initial state, with an empty recorder.
        """


def _declarations(header: str) -> str:
    """The cffi declarations of a C header: its text without the preprocessor lines."""
    return "\n".join(line for line in header.splitlines() if not line.lstrip().startswith("#"))


def native_module():
    """The cffi module (``.ffi``, ``.lib``) of ``plant_kernel.c``, compiled on first use.

    Returns
    -------
    module
        With ``ffi`` and ``lib``; its declarations are ``plant_kernel.h`` (the header the C
        file includes), so the two cannot drift apart.
    """
    from smartjoint.common import native, package_data

    header = package_data.path("smartjoint.design.plant", "plant_kernel.h")
    source = package_data.path("smartjoint.design.plant", "plant_kernel.c")
    return native.load("plant", _declarations(header.read_text()), source, includes=(header.parent,))


# The joint laws' arrays (``joints.JointLaws``) that sj_plant and sj_stick hold, by the laws' names.
LAW_FIELDS = ("s0", "s1", "s2", "fc", "fd", "vs", "arm")


class NativeStructs:
    """The cffi module of ``plant_kernel.c`` and the numpy arrays its structs point into: what a
    C kernel of either friction scheme sets up (``fixed_step``, ``stick_exact``).

    The fields of the C structs carry the names of the Python attributes they hold, so a struct
    is filled from name lists (:meth:`numbers`, :meth:`pointers`). An array handed to
    :meth:`pointer` is kept as long as this object, so the C structs never point into freed
    memory; ``ffi`` and ``lib`` are the module's.
    """

    def __init__(self) -> None:
        module = native_module()
        self.ffi, self.lib = module.ffi, module.lib
        self._kept: list[np.ndarray] = []

    def pointer(self, array):
        """A ``double *`` to the array's float values (C-ordered; a copy only where it is not).

        Parameters
        ----------
        array : array_like
            The values; kept alive with this object.

        Returns
        -------
        cdata
            ``double *``.
        """
        array = np.ascontiguousarray(array, dtype=float)
        self._kept.append(array)
        return self.ffi.cast("double *", self.ffi.from_buffer(array))

    def pointers(self, source, names: tuple[str, ...]) -> dict:
        """Struct fields that point into arrays of the same names (see :meth:`pointer`).

        Parameters
        ----------
        source : object
            Has the arrays as attributes ``names``.
        names : tuple of str
            The fields, named as the attributes.

        Returns
        -------
        dict
            Field name → ``double *``.
        """
        return {name: self.pointer(getattr(source, name)) for name in names}

    @staticmethod
    def numbers(source, names: tuple[str, ...]) -> dict:
        """Struct fields that hold numbers of the same names.

        Parameters
        ----------
        source : object
            Has the numbers (sizes, step lengths) as attributes ``names``.
        names : tuple of str
            The fields, named as the attributes.

        Returns
        -------
        dict
            Field name → number.
        """
        return {name: getattr(source, name) for name in names}

    def shared(self, state: State, names: tuple[str, ...]) -> dict:
        """Pointers into the state's arrays, which C then writes and numpy reads.

        Parameters
        ----------
        state : State
            The arrays ``names`` are made C-ordered floats in place first (where they are, as
            ``State`` makes them, they stay the same objects).
        names : tuple of str
            Attributes of ``state``, named as the fields of the C state struct.

        Returns
        -------
        dict
            Field name → ``double *``.
        """
        for name in names:
            setattr(state, name, np.ascontiguousarray(getattr(state, name), dtype=float))
        return self.pointers(state, names)

    def record(self, recorder: Recorder):
        """The ``sj_record`` struct that writes the recorded rows into ``recorder``'s arrays.

        Parameters
        ----------
        recorder : Recorder
            Its ``fields()``, in the struct's order.

        Returns
        -------
        cdata
            ``sj_record *``.
        """
        return self.ffi.new("sj_record *", {name: self.pointer(array) for name, array in recorder.fields().items()})


def choose_kernel(run: PlantRun, what: str, plant, compiled, mirror, failures: list[str]) -> Kernel:
    """A friction scheme's C kernel or its numpy mirror, as ``run.backend`` asks
    (``native.choose``), on a new state and recorder.

    Parameters
    ----------
    run : PlantRun
        The run: its backend, initial state and number of recorded rows.
    what : str
        The simulation as the warning of a fallback to Python names it.
    plant
        The scheme's constant data: ``ET`` (Eᵀ, l × n), ``l`` joints and ``ny`` sensors.
    compiled, mirror : callable
        The C and the numpy kernel, each called with ``(plant, state, recorder)``.
    failures : list of str
        Why the scheme's C kernel is unavailable on this machine (reported once).

    Returns
    -------
    Kernel
        The chosen kernel; state and recorder shared with numpy.
    """
    from smartjoint.common import native

    state = State(plant.ET, run.initial_state)
    recorder = Recorder(run.rows, plant.l, plant.ny)
    return native.choose(
        run.backend,
        what,
        lambda: compiled(plant, state, recorder),
        lambda: mirror(plant, state, recorder),
        failures,
        stacklevel=4,  # the warning names the caller of the scheme's kernel(), as without this helper
    )


__all__ = [
    "LAW_FIELDS",
    "Kernel",
    "NativeStructs",
    "PlantRun",
    "Recorder",
    "Scheme",
    "State",
    "choose_kernel",
    "native_module",
]
