"""Where a method stopped (``Result.status``), the never-worse rule on a robust method's own cost,
``FIX`` poses, and what ``popbench solve`` says about them (docs/solve.md, docs/never_worse.md).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import grid_g2o, require_dataset
from scipy.optimize import least_squares

from popbench import cli, objective
from popbench.errors import PopbenchError
from popbench.methods import METHODS, Budget, MethodRecord, Result, get_method
from popbench.outliers import add_false_loop_closures, precision_recall
from popbench.problems.distributed import DistributedProblem
from popbench.solvers.chordal import chordal_initialisation
from popbench.solvers.initial import with_start
from popbench.solvers.lm import solve_graph
from popbench.status import Status

STATUS_FIELDS = {field for field in Status.__dataclass_fields__}
LEARNED = {name for name, record in METHODS.items() if record.learned}


def solve_cli(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    code = cli.main(["solve", *args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_chi2_gradient_matches_finite_differences(small_graph, rng) -> None:
    poses = small_graph.poses + rng.normal(0.0, 0.05, small_graph.poses.shape)
    analytic = objective.gradient(small_graph, poses, "chi2")
    step, numeric = 1e-6, np.zeros_like(poses)
    for index in np.ndindex(*poses.shape):  # test reference only: 90 coordinates
        plus, minus = poses.copy(), poses.copy()
        plus[index] += step
        minus[index] -= step
        numeric[index] = (
            objective.chi2(small_graph, plus) - objective.chi2(small_graph, minus)
        ) / (2 * step)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-5)


def test_lm_chi2_matches_scipy_least_squares(small_graph) -> None:
    """Correlated information (cross terms everywhere): LM on chi2 reaches SciPy's optimum of
    the whitened g2o errors, and its reported gradient norm is ∇chi2's."""
    start = chordal_initialisation(small_graph)
    outcome = solve_graph(small_graph, start, cost="chi2")
    sqrt_information = np.swapaxes(np.linalg.cholesky(small_graph.information), -1, -2)

    def whitened(free: np.ndarray) -> np.ndarray:
        poses = np.vstack([start[:1], free.reshape(-1, 3)])
        errors = objective.g2o_errors(small_graph, poses)
        return np.einsum("mij,mj->mi", sqrt_information, errors).ravel()

    fit = least_squares(whitened, start[1:].ravel(), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert outcome.converged
    assert outcome.history[-1] == pytest.approx(2.0 * fit.cost, rel=1e-9)
    assert outcome.history[-1] == pytest.approx(objective.chi2(small_graph, outcome.poses))
    gradient = objective.gradient(small_graph, outcome.poses, "chi2")[1:]
    assert outcome.gradient_norm == pytest.approx(np.max(np.abs(gradient)), rel=1e-6, abs=1e-12)


def test_anisotropy_is_one_for_F_weights_only() -> None:
    kappa, tau = 400.0, 100.0
    isotropic = np.diag([tau, tau, kappa])[None]
    assert objective.anisotropy(isotropic) == pytest.approx([1.0])
    stretched = np.diag([400.0, 25.0, kappa])[None]  # τ = 2·400·25/425; eigenvalues 400/τ, 25/τ
    assert objective.anisotropy(stretched) == pytest.approx([16.0])


@pytest.mark.parametrize(
    "method", [pytest.param(m, marks=pytest.mark.slow) if m in LEARNED else m for m in METHODS]
)
def test_every_method_reports_its_status(
    capsys: pytest.CaptureFixture, tmp_path, method: str
) -> None:
    path = grid_g2o(tmp_path / "grid.g2o")
    code, out, err = solve_cli(capsys, str(path), "--method", method, "--robots", "2")
    assert code == 0, err
    record = json.loads(solve_cli(capsys, str(path), "--method", method, "--json")[1])
    status = record["status"]
    assert set(status) == STATUS_FIELDS
    assert isinstance(status["converged"], bool) and status["rounds"] >= 0
    assert np.isfinite(status["gradient_norm"]) and status["gradient_norm"] >= 0.0
    assert status["cost"] <= status["start_cost"] * (1.0 + 1e-12)
    assert record["objective"] == ("chi2" if "objective" in cli_options(method) else "F")
    assert ("status" in out) and ("rounds" in out)


def cli_options(method: str) -> tuple[str, ...]:
    from popbench.methods import method_options

    return method_options(method)


def test_not_converged_is_said_on_stderr(capsys: pytest.CaptureFixture, tmp_path) -> None:
    path = grid_g2o(tmp_path / "grid.g2o")
    args = (str(path), "--method", "mm-pgo", "--robots", "2", "--iterations", "2", "--json")
    code, out, err = solve_cli(capsys, *args)
    assert code == 0 and not json.loads(out)["status"]["converged"]
    assert "mm-pgo: not converged after 2 rounds (‖∇‖ = " in err
    code, out, err = solve_cli(capsys, str(path), "--method", "lm", "--json")
    assert json.loads(out)["status"]["converged"] and "not converged" not in err


@pytest.mark.dataset
@pytest.mark.slow  # 1,000 MM rounds on 3,500 poses: ≈ 16 s
def test_mm_pgo_on_m3500_is_not_converged_after_its_default_rounds(
    capsys: pytest.CaptureFixture,
) -> None:
    require_dataset("m3500")
    code, out, err = solve_cli(capsys, "m3500", "--method", "mm-pgo", "--robots", "7", "--json")
    record = json.loads(out)
    assert code == 0 and record["iterations"] == 1000 and not record["status"]["converged"]
    assert "not converged after 1000 rounds (‖∇‖ = " in err


def test_f_on_anisotropic_information_is_said_once(capsys: pytest.CaptureFixture, tmp_path) -> None:
    isotropic = grid_g2o(tmp_path / "grid.g2o")
    stretched = tmp_path / "stretched.g2o"
    stretched.write_text(isotropic.read_text().replace("100 0 0 100 0 400", "100 30 0 20 0 400"))
    for path, expected in ((isotropic, 0), (stretched, 1)):
        _, out, err = solve_cli(capsys, str(path), "--method", "mm-pgo", "--json")
        assert json.loads(out)["objective"] == "F"
        assert err.count("minimised F (paper eq. 1") == expected
    _, out, err = solve_cli(capsys, str(stretched), "--method", "lm", "--json")
    assert json.loads(out)["objective"] == "chi2" and "minimised F" not in err
    code, _, err = solve_cli(capsys, str(stretched), "--method", "mm-pgo", "--objective", "chi2")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "minimises F only" in err


@pytest.mark.dataset
@pytest.mark.parametrize("cost", ["F", pytest.param("chi2", marks=pytest.mark.slow)])
def test_gnc_keeps_its_answer_on_fr079_with_false_loop_closures(cost: str) -> None:
    """100 vertigo-random loop closures added to FR079 (seed 1), solved as a user's file would be
    (no injected-outlier mask, so the never-worse rule applies): GNC's map is the clean optimum
    of its cost and the rule keeps it (it returned the odometry start when it judged on F over
    every edge)."""
    clean = require_dataset("fr079")
    loops = int(np.count_nonzero(clean.kinds == 1))
    corrupted, added = add_false_loop_closures(clean, 100 / loops, "vertigo-random", seed=1)
    assert added.sum() == 100
    problem = with_start(DistributedProblem.single_robot(corrupted), "odometry")
    result = get_method("gnc")(problem, Budget(), objective=cost)
    precision, recall = precision_recall(~result.inlier_mask, added)
    assert precision >= 0.95 and recall >= 0.95
    assert result.extras["never_worse"] == "method"
    assert result.status.robust == "tls" and result.status.cost < result.status.start_cost
    optimum = solve_graph(clean, chordal_initialisation(clean), 200, cost=cost)
    clean_cost = objective.cost_value(clean, result.poses, cost)
    assert clean_cost <= 1.01 * objective.cost_value(clean, optimum.poses, cost)
    # judged on F over every edge, the false ones included, the start would have won
    assert result.F > objective.objective(corrupted, problem.graph.poses) or cost == "chi2"


def _worse_than_the_start(problem, budget, **_):
    """A registered method for the summary test: the start moved away, every edge flagged."""
    poses = problem.graph.poses + 1.0
    costs = objective.evaluate(problem.graph, poses)
    return Result(
        poses=poses,
        **costs._asdict(),
        wall_s=0.0,
        parallel_s=0.0,
        iterations=1,
        history=np.array([objective.objective(problem.graph), costs.F]),
        inlier_mask=np.zeros(problem.graph.num_edges, dtype=bool),
    )


def test_summary_says_when_the_start_is_returned(
    capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch, tmp_path
) -> None:
    from popbench import methods

    record = MethodRecord("worse", "test_solve_status:_worse_than_the_start", "Worse")
    monkeypatch.setitem(methods.METHODS, "worse", record)
    path = grid_g2o(tmp_path / "grid.g2o")
    code, out, _ = solve_cli(capsys, str(path), "--method", "worse")
    flags_line = next(line for line in out.splitlines() if "edges flagged" in line)
    assert code == 0 and "START" in flags_line
    code, out, _ = solve_cli(capsys, str(path), "--method", "worse", "--json")
    assert json.loads(out)["extras"]["never_worse"] == "start"


@pytest.mark.parametrize("method", ["lm", "gnc"])
def test_fix_poses_are_held_bitwise(small_graph, method: str) -> None:
    fixed = np.array([3, 17])
    values = small_graph.ground_truth  # the file's poses of the FIX vertices
    graph = small_graph.replace(poses=values, fixed=fixed)
    problem = with_start(DistributedProblem.single_robot(graph), "odometry")
    start = problem.graph.poses
    assert np.array_equal(start[fixed], values[fixed])  # the start holds them too
    result = get_method(method)(problem, Budget(iterations=50))
    assert np.array_equal(result.poses[fixed], values[fixed])
    assert not np.array_equal(result.poses[0], start[0])  # vertex 0 is free
    assert result.status.converged and result.status.gradient_norm < 1e-3


def test_one_fix_pose_is_every_method_s_gauge_and_more_are_refused(small_graph) -> None:
    values = small_graph.ground_truth
    plain = with_start(DistributedProblem.single_robot(small_graph.replace(poses=values)), "given")
    fixed = with_start(
        DistributedProblem.single_robot(small_graph.replace(poses=values, fixed=np.array([7]))),
        "given",
    )
    free = get_method("mm-pgo")(plain, Budget(iterations=20))
    held = get_method("mm-pgo")(fixed, Budget(iterations=20))
    assert np.array_equal(held.poses[7], values[7])
    assert held.F == pytest.approx(free.F, rel=1e-9)  # a rigid motion: same cost
    two = small_graph.replace(poses=values, fixed=np.array([2, 7]))
    with pytest.raises(PopbenchError, match="cannot hold 2 FIX poses"):
        get_method("mm-pgo")(DistributedProblem.single_robot(two), Budget(iterations=2))


def test_fix_poses_refused_by_the_command_exit_2(
    capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch, small_graph
) -> None:
    from popbench.harness import solve as solve_module

    two = small_graph.replace(fixed=np.array([2, 7]))
    monkeypatch.setattr(
        solve_module,
        "build_problem",
        lambda *args, **kwargs: DistributedProblem.single_robot(two),
    )
    code, _, err = solve_cli(capsys, "loop30", "--method", "cc-pgo")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "FIX" in err


@pytest.mark.parametrize(("method", "fix"), [("lm", "5 12"), ("gnc", "5 12"), ("mm-pgo", "12")])
def test_fix_lines_hold_their_poses_bitwise_through_the_command(
    capsys: pytest.CaptureFixture, tmp_path, method: str, fix: str
) -> None:
    from popbench.io import read_graph

    path = grid_g2o(tmp_path / "grid.g2o")
    path.write_text(path.read_text() + f"FIX {fix}\n")
    out = tmp_path / "out.g2o"
    args = (str(path), "--method", method, "--init", "odometry", "--output", str(out), "--json")
    code, _, err = solve_cli(capsys, *args)
    assert code == 0, err
    given, solved = read_graph(path), read_graph(out)
    fixed = np.array([int(i) for i in fix.split()])
    assert np.array_equal(given.fixed, fixed) and np.array_equal(solved.fixed, fixed)
    assert np.array_equal(solved.poses[fixed], given.poses[fixed])
    assert not np.array_equal(solved.poses, given.poses)


def test_two_fix_lines_refused_by_a_method_that_holds_one(
    capsys: pytest.CaptureFixture, tmp_path
) -> None:
    path = grid_g2o(tmp_path / "grid.g2o")
    path.write_text(path.read_text() + "FIX 5\nFIX 12\n")
    code, _, err = solve_cli(capsys, str(path), "--method", "cc-pgo", "--robots", "2")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "cannot hold 2 FIX poses fixed" in err
