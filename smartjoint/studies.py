"""Studies that combine the design tools: the reduction example of paper Section 4.3 (Fig. 10)."""

from __future__ import annotations

import numpy as np

from smartjoint.design.friction import lugre
from smartjoint.design.structure import modal
from smartjoint.design.reduction import krylov as reduction
from smartjoint.design import plant as simulate
from smartjoint.common.errors import ModelError
from smartjoint.design.structure.fem import build_model

WINDOWS = (0.05, 0.1, 0.2, 0.5)  # s: RMS windows of the friction-moment comparison


def joint_laws(design) -> list[lugre.LuGreParameters]:
    """LuGre parameters per joint: paper Table 1 by joint type."""
    return [lugre.TABLE_1[j.type] for j in design.joints]


def parse_normal_forces(text: str, design) -> np.ndarray:
    """``"400,0,0"`` → one F_N per joint, in the design's joint order."""
    try:
        values = np.array([float(v) for v in text.split(",")], dtype=float)
    except ValueError:
        raise ModelError(f"--normal-force: {text!r} — expected comma-separated numbers [N], one per joint") from None
    if values.size != len(design.joints) or not np.all(np.isfinite(values)) or np.any(values < 0):
        raise ModelError(f"--normal-force: {text!r} — need {len(design.joints)} finite values >= 0 "
                         f"(joints {', '.join(j.name for j in design.joints)})")
    return values


def reduction_study(design, normal_forces: np.ndarray, considered: int = 100, keep: int = 60,
                    krylov: tuple[int, ...] = (0, 2), krylov_joints: list[int] | None = None, duration: float = 0.5,
                    step: float = 5e-5, progress=print) -> dict:
    """Full model (all modes of Eq. 5) against reduced models with 0…K Krylov vectors under the
    paper's tip pulse: the friction forces of Fig. 10 and the error metrics of Section 4."""
    if not design.joints:
        raise ModelError("design has no [[joints]]: the reduction study needs at least one friction joint")
    fe = build_model(design, joints="released")
    progress(f"      all {fe.n_dof} modes of the released truss (the full model) …")
    everything = modal.solve_modes(fe, fe.n_dof)
    full = modal.modal_model(fe, everything)
    first = modal.Modes(everything.omega[:considered], everything.shapes[:, :considered],
                        everything.damping[:considered])
    laws = joint_laws(design)
    controller = simulate.ConstantNormalForce(normal_forces, 1e-3)
    pulse = simulate.triangular_pulse(directions=np.ones(len(design.disturbances)))  # 200 N along every input
    considered = min(considered, fe.n_dof)
    keep = min(keep, considered)
    progress(f"      full model: {full.n_states} states, {duration:g} s at {step:g} s")
    reference = simulate.simulate(full, laws, controller, pulse, duration, step, energy_books=False)
    active = int(np.argmax(normal_forces))
    ref_u = reference.friction_force[:, active]
    band = float(first.omega[-1])
    runs = []
    for count in krylov:
        reduced = reduction.reduce(fe, first, keep, count, krylov_joints=krylov_joints)
        result = simulate.simulate(reduced.model, laws, controller, pulse, duration, step, energy_books=False)
        diff = result.friction_force[:, active] - ref_u
        errors = {f"{w:g}": float(np.sqrt(np.mean(diff[reference.time <= w] ** 2))
                                 / np.sqrt(np.mean(ref_u[reference.time <= w] ** 2))) for w in WINDOWS if w <= duration}
        metrics = reduction.error_metrics(fe, full, reduced.model, band)
        runs.append({"krylov_per_joint": count, "states": reduced.model.n_states, "result": result,
                     "reduction": reduced, "friction_rms_error": errors, "metrics": metrics,
                     "energy_measure_ratio": result.energy_measure() / reference.energy_measure()})
        progress(f"      {keep} modes + {count} Krylov vector(s): friction RMS error "
                 + ", ".join(f"{100 * e:.1f} % (0–{w} s)" for w, e in errors.items()))
    return {"fe": fe, "full": full, "first": first, "reference": reference, "runs": runs, "active": active,
            "considered": considered, "keep": keep, "duration": duration, "step": step,
            "joint_names": [j.name for j in design.joints], "normal_forces": normal_forces.tolist()}


def study_summary(study: dict) -> dict:
    """The JSON-able part of a reduction study."""
    hankel = study["runs"][0]["reduction"].hankel
    return {
        "joints": study["joint_names"], "normal_forces": study["normal_forces"],
        "active_joint": study["joint_names"][study["active"]],
        "full_states": study["full"].n_states, "considered_modes": study["considered"], "kept_modes": study["keep"],
        "duration_s": study["duration"], "step_s": study["step"],
        "hankel_uv": hankel["uv"].tolist(),
        "runs": [{"krylov_per_joint": r["krylov_per_joint"], "states": r["states"],
                  "kept_modes": (r["reduction"].kept_modes + 1).tolist(),
                  "krylov_frequencies_hz": (r["reduction"].model.omega[study["keep"]:] / (2 * np.pi)).tolist(),
                  "friction_rms_error": r["friction_rms_error"], "energy_measure_ratio": r["energy_measure_ratio"],
                  "metrics": r["metrics"]} for r in study["runs"]],
    }


def plot_study(study: dict, folder) -> list:
    """hankel.png (Fig. 9), friction_moment.png (Fig. 10), energy.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from pathlib import Path

    folder = Path(folder)
    written = []
    first = study["first"]
    fe = study["fe"]
    considered = modal.modal_model(fe, first)
    fig, ax = plt.subplots(figsize=(7, 3.5))
    control_u = (considered.joint_input**2) / (4 * considered.damping * considered.omega)[:, None]
    for j, name in enumerate(study["joint_names"]):
        ax.semilogy(np.arange(1, first.omega.size + 1), control_u[:, j], ".", label=f"joint {name}")
    kept = study["runs"][0]["reduction"].kept_modes
    ax.semilogy(kept + 1, reduction.hankel_values(considered)["uv"][kept], "o", mfc="none", color="k",
                label=f"kept ({kept.size})")
    written.append(_save(fig, ax, folder / "hankel.png", "mode", "w_i^c (Eq. 17)", "Controllability of the modes by each joint (Fig. 9)"))

    ref = study["reference"]
    a = study["active"]
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(ref.time, ref.friction_force[:, a], "k", lw=1.2, label=f"full ({study['full'].n_states} states)")
    for r in study["runs"]:
        ax.plot(r["result"].time, r["result"].friction_force[:, a], lw=0.9,
                label=f"{study['keep']} modes + {r['krylov_per_joint']} Krylov ({r['states']} states)")
    written.append(_save(fig, ax, folder / "friction_moment.png", "t [s]", f"u_R of {study['joint_names'][a]}", "Friction moment: full vs reduced (Fig. 10)"))

    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.semilogy(ref.time, np.maximum(ref.energy, 1e-12), "k", label="full")
    for r in study["runs"]:
        ax.semilogy(r["result"].time, np.maximum(r["result"].energy, 1e-12), lw=0.9,
                    label=f"{study['keep']} modes + {r['krylov_per_joint']} Krylov")
    written.append(_save(fig, ax, folder / "energy.png", "t [s]", "½xᵀx [J]", "Structural energy after the tip pulse"))
    return written


def _save(fig, ax, path, xlabel: str, ylabel: str, title: str):
    import matplotlib.pyplot as plt

    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def study_markdown(study: dict) -> str:
    s = study_summary(study)
    lines = ["## Model reduction (paper Section 4, Figs. 9–10)", "",
             f"Joints {', '.join(s['joints'])} with F_N = {s['normal_forces']} N, tip pulse 200 N over 40 ms in y and z. "
             f"Full model: all modes of the released truss ({s['full_states']} states); reduced: {s['kept_modes']} "
             f"of the first {s['considered_modes']} modes by Hankel singular values, plus Krylov vectors for the "
             f"active joint {s['active_joint']}. Plant step {s['step_s']:g} s.", "",
             "| Krylov vectors | states | friction RMS error " + " | ".join(f"0–{w} s" for w in
                                                                        s["runs"][0]["friction_rms_error"])
             + " | static compliance error | H∞ u→v (rel., band) | H∞ w→y (rel.) |",
             "|---:|---:|" + "---:|" * (len(s["runs"][0]["friction_rms_error"]) + 3)]
    for r in s["runs"]:
        m = r["metrics"]
        lines.append(f"| {r['krylov_per_joint']} | {r['states']} | "
                     + " | ".join(f"{100 * e:.1f} %" for e in r["friction_rms_error"].values())
                     + f" | {100 * m['static_compliance']['relative_error']:.2f} % | {100 * m['uv']['hinf_relative']:.1f} %"
                     f" | {100 * m['wy']['hinf_relative']:.2f} % |")
    lines += ["", "The stick–slip trajectory is sensitive: small model differences shift the stick/slip instants, "
              "so the error grows with the window (docs/simulation.md).", "",
              "![hankel](hankel.png)", "", "![friction moment](friction_moment.png)", "", "![energy](energy.png)", ""]
    return "\n".join(lines)
