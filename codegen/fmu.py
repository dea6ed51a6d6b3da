"""FMI co-simulation units of the generated controllers and of the nonlinear truss plant.

``smartjoint fmu`` packs what the project already generates into a Functional Mock-up Unit, so a
controller or the plant can be dropped into Simulink, OpenModelica, Dymola or any co-simulation
master and give the project's numbers there:

* a **controller FMU** (:func:`controller_fmu`) wraps the firmware's own generated law
  (``<prefix>_siso.c`` or ``<prefix>_clqg.c``, float or double build) — no second implementation —
  behind the FMI 2.0 or 3.0 co-simulation API, with the normal-force limits and the law's settings
  as tunable parameters and the sample time as the only communication step;
* a **plant FMU** (:func:`plant_fmu`) wraps the project's fixed-step plant kernel
  (``design/plant/plant_kernel.c``) with the design's reduced modal model and LuGre joints as data,
  exact to the bit, and the study's tip pulse.

Each FMU holds ``modelDescription.xml``, the binary for this platform and, under ``sources/``, every
C file it was built from with the FMI headers of the installed FMPy and a build description, so
the unpacked FMU compiles alone on other platforms. The files are rendered from
``templates/fmu/`` (the FMI layer ``fmi{2,3}_functions.c``, the model ``fmu_model.c`` behind
``fmu_model.h``) and packed deterministically: the same inputs give a byte-identical FMU.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smartjoint.codegen import build, fmi_headers, fmu_variables, generate, rendering
from smartjoint.common import law_registry, output_path, package_data
from smartjoint.common.errors import ModelError
from smartjoint.design.plant import fixed_step
from smartjoint.design.plant.interface import ConstantNormalForce
from smartjoint.design.plant.kernel import LAW_FIELDS, PlantRun

LAWS = {law.name: law.title for law in law_registry.LAWS.values()}
VERSIONS = (2, 3)
UNITS = {
    "N": (("kg", 1), ("m", 1), ("s", -2)),
    "m": (("m", 1),),
    "m/s": (("m", 1), ("s", -1)),
    "s": (("s", 1),),
    "J": (("kg", 1), ("m", 2), ("s", -2)),
}
# The FMI functions the templates define themselves (the rest of FMI 3 refuses, from the header).
_FMI3_OWN = {
    "fmi3SetDebugLogging", "fmi3EnterInitializationMode", "fmi3ExitInitializationMode", "fmi3Terminate",
    "fmi3Reset", "fmi3GetFloat64", "fmi3GetInt32", "fmi3SetFloat64", "fmi3GetFMUState", "fmi3SetFMUState",
    "fmi3FreeFMUState", "fmi3SerializedFMUStateSize", "fmi3SerializeFMUState", "fmi3DeserializeFMUState",
    "fmi3DoStep",
}  # fmt: skip
_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # every member's date: the FMU depends on its inputs alone


def _controller_rules(sample_time: float, exchange: str = "feedthrough") -> list[str]:
    timing = (
        "The outputs at a communication point are the law's step from the inputs set at that point (direct "
        "feedthrough): set the inputs, read the outputs, then step."
        if exchange == "feedthrough"
        else "The outputs are the law's step from the inputs of the last step, held until the next (no feedthrough; "
        "F_N^max before the first): for masters that step every FMU, then pass outputs on."
    )
    return [
        f"The communication step is the sample time, {sample_time!r} s, and nothing else.",
        timing,
        "The normal-force limits and the law's settings are tunable between steps; the safe normal force is not.",
    ]


def _plant_rules(plant_step: float) -> list[str]:
    return [
        f"The plant steps {plant_step!r} s; a communication step is any whole number of plant steps.",
        "A normal force acts when it is set (the piezo taken as instantaneous); the disturbance inputs are held "
        "over a communication step and added to the built-in tip pulse (pulse.amplitude, pulse.duration).",
    ]


@dataclass(frozen=True)
class Fmu:
    """A written FMU: its path, model identifier, FMI version, variables and what it holds."""

    path: Path
    identifier: str
    fmi: int
    variables: list
    members: list[str]
    binary: str


def identifier_of(path) -> str:
    """The model identifier an FMU file name gives (``truss.fmu`` → ``truss``).

    Raises
    ------
    ModelError
        The name is not ``<C identifier>.fmu``.
    """
    path = Path(path)
    if path.suffix != ".fmu" or not _IDENTIFIER.fullmatch(path.stem):
        raise ModelError(
            f"-o: {path.name!r} — an FMU is named <model identifier>.fmu, the identifier letters, digits and _ "
            "not starting with a digit"
        )
    return path.stem


def _check_version(fmi: int) -> None:
    if fmi not in VERSIONS:
        raise ModelError(f"--fmi: {fmi!r} — allowed: 2, 3")


EXCHANGES = ("feedthrough", "held")  # controller FMUs: outputs from this point's inputs, or held from the last step


def controller_fmu(artifact, law: str, path, fmi: int = 2, real: str = "double", prefix: str = "smartjoint",
                   stop_time: float = 1.0, exchange: str = "feedthrough") -> Fmu:  # fmt: skip
    """Write the controller FMU of one generated law.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design the law is generated from.
    law : str
        A law of the registry (``common.law_registry``) by name.
    path : path-like
        The FMU to write, ``<model identifier>.fmu``.
    fmi : int
        FMI version, 2 or 3.
    real : str
        The law's scalar type, "double" or "float" (the firmware's build).
    prefix : str
        The generated code's prefix.
    stop_time : float
        The default experiment's stop time [s]: the design's study (t_e) where it is known.
    exchange : str
        ``"feedthrough"``: the outputs at a point are the law's step from the inputs set there (the
        firmware's timing, for masters that set inputs before they read outputs: FMPy's loop,
        Simulink, OMSimulator). ``"held"``: the outputs are the step of the last DoStep's inputs,
        held until the next, for masters that step every FMU and then pass outputs on (libcosim);
        the command then acts one sample later (docs/fmu.md).

    Returns
    -------
    Fmu
    """
    if law not in LAWS:
        raise ModelError(f"--law: {law!r} — allowed: {', '.join(LAWS)}")
    if exchange not in EXCHANGES:
        raise ModelError(f"--exchange: {exchange!r} — allowed: {', '.join(EXCHANGES)}")
    if real not in ("float", "double"):
        raise ModelError(f"--real: {real!r} — allowed: float, double")
    _check_version(fmi)
    identifier = identifier_of(path)
    variables = fmu_variables.controller_variables(artifact, law, real)
    name = f"{prefix}_{law}"
    banner = _fmu_banner(rendering.banner(artifact.artifact_sha256, real, "codegen, FMU"))
    laws = generate.render(artifact, real, prefix)
    sources = {key: laws[key] for key in (f"{prefix}_types.h", f"{name}.h", f"{name}.c")}
    entry = law_registry.law(law)

    def row(values, kind: str) -> str:
        return ", ".join(rendering.literal(float(v), kind) for v in np.asarray(values, dtype=float).reshape(-1))

    # The law's own F_N^min (the SISO preload) is the start of its tunable F_N^min.
    low = np.asarray(getattr(artifact, entry.lower_force_field()), dtype=float)
    high = np.asarray(artifact.normal_force_max, dtype=float)
    context = {
        **rendering.naming(banner, prefix, name),
        "title": LAWS[law],
        "sample_time": rendering.literal(artifact.sample_time, "double"),
        "start_normal_force_min": row(low, "double"),
        "start_normal_force_max": row(high, "double"),
        "settings": [{"key": setting.key, "count": values.size, "per_joint": setting.per_joint,
                      "start": row(values, "double")} for setting, values in _settings(artifact, entry)],
        "held": exchange == "held",
        "desired_force": "desired_force" in entry.outputs,
        **{f"law_{part}": fmu_variables.law_fields(sources[f"{name}.h"], prefix, name, part)
           for part in ("state", "output")},  # what a saved state's check reads of the law's structs
    }  # fmt: skip
    description = (
        f"{artifact.name}: {LAWS[law]}, {real} build, from controller artefact {artifact.artifact_sha256[:12]}"
        + (", outputs held from the last step" if exchange == "held" else "")
    )
    return _write(
        path, identifier, fmi, variables, "fmu/fmu_controller.c.j2", context, sources, [f"{name}.c"],
        dict(description=description, stop_time=float(stop_time), step_size=artifact.sample_time, variable_step="false",
             fixed_step=None, rules=_controller_rules(artifact.sample_time, exchange)),
        _controller_dependencies(variables, exchange),
    )  # fmt: skip


def _settings(artifact, entry) -> list[tuple]:
    """Each of the law's settings with its values in the artefact (one per joint, or one), but
    its own F_N^min: that is the start of the tunable ``JOINT_<j>.normal_force_min``."""
    fields = dict(entry.artifact)
    return [
        (s, np.atleast_1d(np.asarray(getattr(artifact, fields[s.key]), dtype=float)))
        for s in entry.settings
        if not s.lower_force
    ]


def _fmu_banner(banner: str) -> str:
    """The generator's banner, naming the command that writes FMUs."""
    return banner.replace("regenerate with `smartjoint codegen`", "regenerate with `smartjoint fmu`")


def _controller_dependencies(variables, exchange: str = "feedthrough") -> dict[int, list[int] | None]:
    """Every output of a controller depends on every input (a law's step at the point); held
    outputs depend on none (they change only in a step)."""
    inputs = [] if exchange == "held" else fmu_variables.references(variables, "input")
    return {v.reference: inputs for v in variables if v.causality == "output"}


def plant_fmu(setup, design, path, fmi: int = 2) -> Fmu:
    """Write the plant FMU of a study set-up: its reduced plant, joints, step and tip pulse.

    Parameters
    ----------
    setup : StudySetup
        The study (``design.control.runs``): plant model, LuGre joints, plant step, pulse.
    design : Design
        The design the set-up is made from (its name and hash, in the banner and description).
    path : path-like
        The FMU to write.
    fmi : int
        FMI version, 2 or 3.

    Returns
    -------
    Fmu
    """
    _check_version(fmi)
    identifier = identifier_of(path)
    pulse = setup.pulse()
    model = setup.plant
    high = np.broadcast_to(np.asarray(setup.normal_force_max, dtype=float), (len(model.joint_names),))
    margin = design.safety.normal_force_margin  # the largest F_N taken: the artefact's measured_normal_force_max
    variables = fmu_variables.plant_variables(model, pulse.amplitude, pulse.duration, pulse.directions,
                                              high + margin * high)  # fmt: skip
    data = plant_data(setup)
    banner = (
        f"/* Generated by smartjoint {rendering.version()} (codegen, FMU) from design sha256 {design.sha256}.\n"
        " * Do not edit: regenerate with `smartjoint fmu --plant`. */"
    )
    context = {
        "banner": banner,
        "plant_step": data["plant_step"],
        "plant_step_decimal": repr(float(setup.plant_step)),
        **{key: data[key] for key in ("n", "l", "m", "ny", "levels")},
        "arrays": data["arrays"],
        "pointer_fields": data["pointer_fields"],
        "pulse_amplitude": _hex(pulse.amplitude),
        "pulse_duration": _hex(pulse.duration),
        "pulse_factors": ", ".join(_hex(v) for v in pulse.directions),
    }
    sources = {
        name: package_data.path("smartjoint.design.plant", name).read_text()
        for name in ("plant_kernel.h", "plant_kernel.c")
    }
    description = f"{design.name}: reduced truss ({data['n']} coordinates) with {data['l']} LuGre joints, fixed step"
    return _write(
        path, identifier, fmi, variables, "fmu/fmu_plant.c.j2", context, sources, ["plant_kernel.c"],
        dict(description=description, stop_time=setup.duration, step_size=setup.sample_time, variable_step="true",
             fixed_step=repr(float(setup.plant_step)), rules=_plant_rules(setup.plant_step)),
        _plant_dependencies(variables, model.joint_names),
    )  # fmt: skip


def _plant_dependencies(variables, joints) -> dict[int, list[int] | None]:
    """A joint's friction force and normal force depend on its normal-force input (F_N acts at
    once); every other output only on the state."""
    reference = {v.name: v.reference for v in variables}
    out: dict[int, list[int] | None] = {}
    for v in variables:
        if v.causality != "output":
            continue
        joint = next((j for j in joints if v.name in (f"JOINT_{j}.friction_force", f"JOINT_{j}.normal_force")), None)
        out[v.reference] = [] if joint is None else [reference[f"SETPOINT_{joint}.normal_force"]]
    return out


def _hex(value: float) -> str:
    """A double as an exact C99 hexadecimal literal."""
    value = float(value)
    if value == 0.0:
        return "-0.0" if np.signbit(value) else "0.0"
    return value.hex()


def plant_data(setup) -> dict:
    """The plant kernel's data of a study's fixed-step plant (``fixed_step`` layout), as C arrays.

    Parameters
    ----------
    setup : StudySetup

    Returns
    -------
    dict
        Sizes, the plant step (a C literal), ``arrays`` (name, size, lines of hexadecimal
        literals) and ``pointer_fields`` (the ``sj_plant`` field each array is).
    """
    held = ConstantNormalForce(np.zeros(len(setup.laws)), setup.sample_time)  # the scheme asks for a sample time only
    run = PlantRun(setup.plant, setup.laws, held, setup.duration, setup.plant_step, None, 1, "python", False, None)
    plant = fixed_step.tables(run)
    fields = {
        "phi": plant.phi, "g0": plant.g0, "g1": plant.g1, "G": plant.G, "ET": plant.ET_padded, "HT": plant.HT,
        "Vy": plant.Vy, "Dy": plant.Dy, "two_xi_w": plant.two_xi_w,
        **{name: getattr(plant.law, name) for name in (*LAW_FIELDS, "bound")},
    }  # fmt: skip
    arrays, pointers = [], []
    for field, values in fields.items():
        flat = np.ascontiguousarray(values, dtype=float).reshape(-1)
        name = f"plant_{field.lower()}" if field != "G" else "plant_joint_compliance"
        literals = [_hex(v) + "," for v in flat] or ["0.0,"]  # C has no empty arrays
        lines = [" ".join(literals[k : k + 4]) for k in range(0, len(literals), 4)]
        arrays.append({"name": name, "size": max(flat.size, 1), "lines": lines})
        pointers.append({"field": field, "array": name})
    return {
        "n": plant.n,
        "l": plant.l,
        "m": plant.m,
        "ny": plant.ny,
        "levels": fixed_step.MAX_HALVINGS + 1,
        "plant_step": _hex(setup.plant_step),
        "arrays": arrays,
        "pointer_fields": pointers,
    }


def _write(path, identifier, fmi, variables, model_template, context, sources, compiled, xml, dependencies) -> Fmu:
    """Render the model and the FMI layer, compile the binary, pack the FMU and put it in place."""
    env = rendering.environment()
    files = dict(sources)
    files.update(fmi_headers.files(fmi))
    files["fmu_model.h"] = env.get_template("fmu/fmu_model.h.j2").render(banner=context["banner"])
    layer = f"fmi{fmi}_functions.c"
    units = [{"name": unit, "base": UNITS.get(unit, ())} for unit in sorted({v.unit for v in variables if v.unit})]
    listed = ["fmu_model.c", *compiled, layer]
    # The token is the hash of everything but itself: the same inputs, the same FMU.
    files = _render_all(env, files, model_template, layer, context, variables, fmi, "{TOKEN}")
    digest = hashlib.sha256("".join(f"{k}\0{files[k]}\0" for k in sorted(files)).encode()).hexdigest()
    token = "{" + "-".join((digest[:8], digest[8:12], digest[12:16], digest[16:20], digest[20:32])) + "}"
    files["fmu_model.c"] = files["fmu_model.c"].replace("{TOKEN}", token)  # its one mention
    outputs = _outputs(variables, dependencies)
    comment = (
        f"Generated by smartjoint {rendering.version()} (codegen, FMU). Do not edit: regenerate with `smartjoint fmu`."
    )
    description = env.get_template(f"fmu/modelDescription{fmi}.xml.j2").render(
        comment=comment, model_name=identifier, token=token, version=rendering.version(), identifier=identifier,
        sources=listed, units=units, variables=variables, outputs=outputs, **xml,
    )  # fmt: skip
    members = {"modelDescription.xml": description.encode()}
    members.update({f"sources/{name}": text.encode() for name, text in files.items()})
    if fmi == 3:
        members["sources/buildDescription.xml"] = (
            env.get_template("fmu/buildDescription.xml.j2")
            .render(comment=comment, identifier=identifier, sources=listed, warnings=" ".join(build.WARNINGS))
            .encode()
        )
    page = "documentation/_main.html" if fmi == 2 else "documentation/index.html"
    members[page] = (
        env.get_template("fmu/documentation.html.j2")
        .render(comment=comment, identifier=identifier, description=xml["description"], fmi=fmi,
                version=rendering.version(), rules=xml["rules"], variables=variables)
        .encode()
    )  # fmt: skip
    binary = f"binaries/{_platform(fmi)}/{identifier}.so"
    members[binary] = compile_binary(files, listed, identifier)
    target = Path(path)
    _pack(target, members)
    return Fmu(target, identifier, fmi, variables, sorted(members), binary)


def _render_all(env, files, model_template, layer, context, variables, fmi, token) -> dict[str, str]:
    """The sources with the model and the FMI layer rendered for ``token``."""
    out = dict(files)
    real_typed = lambda v: v.value.startswith(("m->input.", "m->output.", "m->shown."))  # noqa: E731
    law_real = f"({context['prefix']}_real)" if "prefix" in context else ""
    out["fmu_model.c"] = env.get_template(model_template).render(
        **context, token=token, variables=variables, real_value=real_typed,
        cast=lambda v: law_real if v.value.startswith("m->input.") else "",
    )  # fmt: skip
    unsupported = fmi_headers.unsupported_fmi3(_FMI3_OWN) if fmi == 3 else []
    out[layer] = env.get_template(f"fmu/{layer}.j2").render(banner=context["banner"], unsupported=unsupported)
    return out


def _outputs(variables, dependencies) -> list[dict]:
    """ModelStructure entries: 1-based index, value reference and dependencies (both ways)."""
    index = {v.reference: k for k, v in enumerate(variables, start=1)}
    return [
        {
            "index": index[v.reference],
            "reference": v.reference,
            "dependencies": None
            if dependencies.get(v.reference) is None
            else [index[r] for r in dependencies[v.reference]],
            "reference_dependencies": dependencies.get(v.reference) or [],
        }
        for v in variables
        if v.causality == "output"
    ]


def _platform(fmi: int) -> str:
    import fmpy

    return fmpy.platform if fmi == 2 else fmpy.platform_tuple


def compile_binary(files: dict[str, str], sources: list[str], identifier: str, flags: list[str] | None = None) -> bytes:
    """The shared library of an FMU's sources, compiled with the warning set of the generated C
    (any warning an error), only the FMI functions exported.

    Parameters
    ----------
    files : dict of str to str
        The FMU's ``sources/`` folder: file name → text.
    sources : list of str
        The translation units.
    identifier : str
    flags : list of str, optional
        Default :data:`build.FLAGS`.

    Returns
    -------
    bytes
    """
    compiler = os.environ.get("CC", "cc")
    if shutil.which(compiler) is None:
        raise ModelError(f"fmu: no C compiler {compiler!r} found (install one or set CC)")
    with tempfile.TemporaryDirectory(prefix="smartjoint-fmu-") as scratch:
        work = Path(scratch)
        for name, text in files.items():
            (work / name).write_text(text)
        library = work / f"{identifier}.so"
        command = [compiler, *(flags or build.FLAGS), "-fPIC", "-shared", "-fvisibility=hidden", "-I", str(work)]
        done = subprocess.run(
            [*command, *(str(work / s) for s in sources), "-o", str(library), "-lm"], capture_output=True, text=True
        )
        if done.returncode != 0:
            first = next((line for line in done.stderr.splitlines() if "error" in line), done.stderr.strip()[:300])
            raise ModelError(f"fmu: compiling the FMU's sources failed: {first.replace(str(work) + os.sep, '')}")
        return library.read_bytes()


def _pack(target: Path, members: dict[str, bytes]) -> None:
    """Zip the members deterministically into a temporary file beside ``target``, then move it
    into place: never a half-written FMU, and an existing one replaced only whole."""
    with output_path.writing(target, binary=True) as stream:  # the output rule, whole or not at all
        with zipfile.ZipFile(stream, "w", zipfile.ZIP_DEFLATED) as archive:
            for name in sorted(members):
                info = zipfile.ZipInfo(name, _ZIP_TIME)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = (0o755 if name.endswith(".so") else 0o644) << 16
                archive.writestr(info, members[name])


__all__ = [
    "EXCHANGES",
    "LAWS",
    "VERSIONS",
    "Fmu",
    "compile_binary",
    "controller_fmu",
    "identifier_of",
    "plant_data",
    "plant_fmu",
]
