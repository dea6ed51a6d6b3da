"""Modal state space (Eq. 11–12), Hankel selection (Eq. 17–18) and Krylov vectors (Eq. 24–29)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from smartjoint.design import reduction
from smartjoint.design.structure import modal
from smartjoint.design.structure.fem import build_model
from smartjoint.design.structure.spec import parse_design

pytestmark = pytest.mark.numerics  # run again by the portability leg (.ci/portability)


@pytest.fixture(scope="module")
def small():
    from conftest import small_truss

    fe = build_model(parse_design(small_truss()), joints="released")
    return fe, modal.solve_modes(fe, fe.n_dof)


def test_state_space_matches_the_fe_model_frequency_response(small):
    """All modes: v/u_R and y/w of Eq. 11–12 equal the direct FE solve (K − ω²M + jωD)⁻¹."""
    fe, modes = small
    full = modal.modal_model(fe, modes)
    A, B, H, Cv, Cy = full.state_space()
    K, M = fe.stiffness.toarray(), fe.mass.toarray()
    Phi = modes.shapes
    D = M @ Phi @ np.diag(2 * modes.damping * modes.omega) @ Phi.T @ M  # modal damping in z
    for w in (2 * np.pi * 3.0, 2 * np.pi * 40.0):
        z = np.linalg.solve(K - w**2 * M + 1j * w * D, np.column_stack([fe.E, fe.F]))
        direct_uv = 1j * w * fe.E.T @ z[:, :2]
        direct_wy = (fe.V + 1j * w * fe.W) @ z[:, 2:]
        x = np.linalg.solve(1j * w * np.eye(A.shape[0]) - A, np.column_stack([B, H]))
        assert np.allclose(Cv @ x[:, :2], direct_uv, rtol=1e-8, atol=1e-12 * np.abs(direct_uv).max())
        assert np.allclose(Cy @ x[:, 2:], direct_wy, rtol=1e-8, atol=1e-12 * np.abs(direct_wy).max())
        # the closed-form response used by the error metrics is the same transfer function
        assert np.allclose(reduction.frequency_response(full, np.array([w]), "uv")[0], direct_uv, rtol=1e-8)


def test_hankel_values_match_the_lyapunov_gramians(small):
    """Eq. 17–18: the closed-form values agree with the exact gramians for ξ ≪ 1 — of the state
    space whose joint inputs (and so v = Bᵀx) are scaled by their references, u_j = √r_j·ũ_j."""
    import control

    fe, modes = small
    few = modal.modal_model(fe, modes, np.arange(8))
    A, B, H, Cv, Cy = few.state_space()
    references = np.array([c.value for c in reduction.channel_references(few) if c.kind == "joint"])
    B = B / np.sqrt(references)
    Wc = control.lyap(A, B @ B.T)
    Wo = control.lyap(A.T, B @ B.T)
    exact = np.sqrt(np.sort(np.linalg.eigvals(Wc @ Wo).real)[::-1])
    closed = np.sort(np.repeat(reduction.hankel_values(few)["uv"], 2))[::-1]
    top = closed[:4]  # the dominant ones, where the diagonal approximation matters
    assert np.allclose(exact[:4], top, rtol=0.02)


def test_krylov_vectors_make_the_static_compliance_exact_and_keep_the_modal_form(small):
    fe, modes = small
    first = modal.Modes(modes.omega[:20], modes.shapes[:, :20], modes.damping[:20])
    plain = reduction.reduce(fe, first, 6, 0)
    corrected = reduction.reduce(fe, first, 6, 2)
    exact = reduction.static_compliance(fe)
    assert np.linalg.norm(reduction.modal_compliance(plain.model) - exact) > 0.05 * np.linalg.norm(exact)
    # One vector per joint spans K⁻¹E: the joint compliance is reproduced to round-off (Eq. 24).
    assert np.allclose(reduction.modal_compliance(corrected.model), exact, rtol=1e-9, atol=1e-12 * np.abs(exact).max())
    basis = corrected.model.basis
    K, M = fe.stiffness, fe.mass
    assert np.allclose(basis.T @ (M @ basis), np.eye(basis.shape[1]), atol=1e-9)
    stiffness = basis.T @ (K @ basis)
    assert np.allclose(stiffness, np.diag(corrected.model.omega**2), rtol=1e-9, atol=1e-9 * stiffness.max())
    assert corrected.model.n_coordinates == 6 + 2 * 2
    # Moment matching (Eq. 23): with K⁻¹E in the basis the low-frequency u_R → v response,
    # jω·EᵀK⁻¹E + O(ω³), is reproduced; without it the compliance error shows directly.
    full = modal.modal_model(fe, modes)
    w = np.array([0.01 * corrected.model.omega[:6].min()])
    exact_g = reduction.frequency_response(full, w, "uv")[0]

    def relative(m):
        return np.linalg.norm(reduction.frequency_response(m, w, "uv")[0] - exact_g) / np.linalg.norm(exact_g)

    assert relative(plain.model) > 0.05
    assert relative(corrected.model) < 1e-3


def test_selection_keeps_the_largest_hankel_values(small):
    fe, modes = small
    considered = modal.modal_model(fe, modes, np.arange(30))
    kept = reduction.select_modes(considered, 5, paths=("uv",))
    values = reduction.hankel_values(considered)["uv"]
    assert set(kept) == set(np.argsort(-values)[:5])
    with pytest.raises(Exception, match="modes: 31"):
        reduction.select_modes(considered, 31)


def test_static_compliance_is_the_sparse_solve(small):
    fe, _ = small
    direct = fe.E.T @ spla.spsolve(fe.stiffness.tocsc(), fe.E)
    assert np.allclose(reduction.static_compliance(fe), direct, rtol=1e-10)


def test_more_krylov_vectors_than_the_space_allows_is_named(small):
    fe, modes = small
    n = fe.n_dof
    with pytest.raises(
        reduction.ModelError, match=rf"Krylov vectors: {n} per joint × 2 joints \+ 10 kept modes .* > {n} DOFs"
    ):
        reduction.reduce(fe, modes, 10, n)


def test_a_dense_solution_that_cannot_fit_is_refused_before_it_allocates(small, monkeypatch):
    """Every mode of a model is a dense N × N solution (the reduction study's full-model reference):
    where that needs more memory than is available, one line names what asked, the DOFs, the
    memory and what to do instead — never numpy's ArrayMemoryError from inside LAPACK."""
    from types import SimpleNamespace

    from conftest import small_truss

    fe, _ = small
    design = parse_design(small_truss())
    needed = modal.dense_memory(fe.n_dof)
    monkeypatch.setattr(modal, "available_memory", lambda: needed - 1)
    refused = rf"n_modes: {fe.n_dof}: a dense eigen solution of {fe.n_dof} DOFs needs .* GB available — ask for at most"
    with pytest.raises(modal.ModelError, match=refused):
        modal.solve_modes(fe, fe.n_dof)
    with pytest.raises(modal.ModelError, match="reduction study: its reference, the full model, is every mode"):
        forces = np.full(len(design.joints), 400.0)
        reduction.reduction_study(design, forces, progress=lambda line: None, released=SimpleNamespace(fe=fe))
    monkeypatch.setattr(modal, "available_memory", lambda: needed)
    assert len(modal.solve_modes(fe, fe.n_dof)) == fe.n_dof
    monkeypatch.setattr(modal, "available_memory", lambda: None)  # unknown: no refusal
    assert len(modal.solve_modes(fe, 3)) == 3


def test_the_sparse_full_model_reference_is_exact_statically_and_in_its_band(small, monkeypatch):
    """Above ``DENSE_REFERENCE_DOFS`` the reduction study's reference is the lowest modes plus the
    static residual of every input (issue 31): its static joint compliance is exact, and its
    u_R → v and w → y responses equal the dense every-mode model's in its band to a small
    fraction of the peak, better than the modes without the residual."""
    from conftest import small_truss

    from smartjoint.design.reduction import study

    fe, modes = small
    design = parse_design(small_truss())
    dense = modal.modal_model(fe, modes)
    correction = reduction.correction_frequency(design.control.sample_time)
    monkeypatch.setattr(study, "DENSE_REFERENCE_DOFS", 0)
    _, sparse, first, band, halved = study._full_model(design, 20, lambda line: None, None, correction)
    assert halved is not None and halved.omega.size == 20 + fe.E.shape[1] + fe.F.shape[1]
    assert first.omega.size == 20 and np.isclose(band, modes.omega[39], rtol=1e-9)
    n_inputs = fe.E.shape[1] + fe.F.shape[1]
    assert sparse.omega.size == 40 + n_inputs
    exact = reduction.static_compliance(fe)
    assert np.linalg.norm(reduction.modal_compliance(sparse) - exact) < 1e-9 * np.linalg.norm(exact)
    modes_only = modal.modal_model(fe, modal.Modes(modes.omega[:40], modes.shapes[:, :40], modes.damping[:40]))
    for path in ("uv", "wy"):
        with_residual = reduction.band_norms(dense, sparse, 0.5 * band, path)
        without = reduction.band_norms(dense, modes_only, 0.5 * band, path)
        assert with_residual["hinf_relative"] < 0.02, (path, with_residual)
        assert with_residual["h2_error"] < 0.6 * without["h2_error"], (path, with_residual, without)
        if path == "uv":  # the joint path: the residual is what the dropped modes leave at the joint
            assert with_residual["hinf_error"] < 0.2 * without["hinf_error"], (path, with_residual, without)


def test_a_sparse_reference_that_moves_when_halved_judges_no_window(small, monkeypatch):
    """The sparse reference is run again from half its modes; a window where the active joint's
    friction force moves by more than ``REFERENCE_CONVERGED`` is "not measured" for every reduced
    model, in the progress lines and in the report's table (issue 31: on a 1000-bay mast the pulse
    has not reached the joints and the errors read thousands of per cent)."""
    from conftest import small_truss

    from smartjoint.design.reduction import study
    from smartjoint.report_reduction import study_markdown

    design = parse_design(small_truss())
    forces = np.array([400.0] + [0.0] * (len(design.joints) - 1))
    monkeypatch.setattr(study, "DENSE_REFERENCE_DOFS", 0)
    lines: list[str] = []
    result = study.reduction_study(
        design, forces, considered=10, keep=6, krylov=(1,), duration=0.1, step=1e-4, progress=lines.append
    )
    convergence = result["reference_convergence"]
    assert set(convergence) == {"0.05", "0.1"} and all(np.isfinite(v) and v >= 0 for v in convergence.values())
    run = result["runs"][0]
    # A threshold between the two windows' values: one judged, one not (whatever this truss gives).
    low, high = sorted(convergence.values())
    assert low < high
    monkeypatch.setattr(study, "REFERENCE_CONVERGED", 0.5 * (low + high))
    text = study.window_text(run["friction_rms_error"], convergence)
    table = study_markdown(result)
    for window, moved in convergence.items():
        judged = moved <= study.REFERENCE_CONVERGED
        assert (f"not measured (0–{window} s)" in text) == (not judged)
        assert (f"{100 * run['friction_rms_error'][window]:.1f} % (0–{window} s)" in text) == judged
    assert "| not measured |" in table
    assert "half its modes moves by" in table and any("half its modes moves by" in line for line in lines)
    # Every window unconverged (threshold 0): no figure is given, in one phrase.
    monkeypatch.setattr(study, "REFERENCE_CONVERGED", 0.0)
    assert study.window_text(run["friction_rms_error"], convergence).startswith("not measured (the reference")
    # The dense reference is exact: every window judged.
    assert "not measured" not in study.window_text(run["friction_rms_error"], None)


def test_smartjoint_reduce_above_the_dense_limit_solves_the_released_truss_once(tmp_path, monkeypatch, capsys):
    """``smartjoint reduce`` on a model above the dense limit (issue 31): one sparse solution of
    the released truss serves the controllers' design model and the study's reference (2 ×
    considered modes), announced by a progress line; the JSON carries the reference's convergence."""
    import json

    import tomli_w
    from conftest import small_truss

    from smartjoint.cli import main
    from smartjoint.design.reduction import study
    from smartjoint.design.structure import solved

    path = tmp_path / "small.toml"
    path.write_text(tomli_w.dumps(small_truss()))
    monkeypatch.setattr(study, "DENSE_REFERENCE_DOFS", 0)
    calls: list[int] = []
    original = solved.solve_modes

    def counted(fe, count, *rest):
        calls.append(count)
        return original(fe, count, *rest)

    monkeypatch.setattr(solved, "solve_modes", counted)
    monkeypatch.setattr(study.modal, "solve_modes", lambda *a, **k: pytest.fail("the study solved modes again"))
    code = main(["reduce", str(path), "--json", "--considered", "12", "--modes", "6", "--duration", "0.05"])
    out, err = capsys.readouterr()
    assert code == 0, err
    summary = json.loads(out)
    assert len(calls) == 1 and calls[0] >= 2 * 12
    assert f"the lowest {calls[0]} modes of the released truss" in err
    assert summary["reference_band_hz"] is not None and set(summary["reference_convergence"]) == {"0.05"}


def test_reduce_takes_the_load_case_from_the_design(tmp_path, capsys):
    """No paper value (issue 36): on a design with F_N 12–150 N the first joint is held at its
    F_N^max and the other at its F_N^min; `reduction_normal_force` replaces that; an all-zero
    `--normal-force` is one line, not a silent 400 N."""
    import json

    import tomli_w
    from conftest import small_truss

    from smartjoint.cli import main

    data = small_truss()
    data["control"] = {"normal_force_min": 12.0, "normal_force_max": 150.0}
    path = tmp_path / "small.toml"
    path.write_text(tomli_w.dumps(data))
    quick = ["--json", "--considered", "12", "--modes", "6", "--duration", "0.02"]
    assert main(["reduce", str(path), *quick]) == 0
    assert json.loads(capsys.readouterr().out)["normal_forces"] == [150.0, 12.0]
    data["control"]["reduction_normal_force"] = [0.0, 90.0]
    path.write_text(tomli_w.dumps(data))
    assert main(["reduce", str(path), *quick]) == 0
    assert json.loads(capsys.readouterr().out)["normal_forces"] == [0.0, 90.0]
    assert main(["reduce", str(path), *quick, "--normal-force", "0,0"]) == 2
    assert "at least one joint > 0 N" in capsys.readouterr().err
    data["control"]["reduction_normal_force"] = [0.0, 0.0]
    path.write_text(tomli_w.dumps(data))
    assert main(["reduce", str(path), *quick]) == 2
    err = capsys.readouterr().err.strip()
    assert "control.reduction_normal_force" in err and "at least one > 0" in err and err.count("\n") == 0, err
