"""The ``safe-nav`` command line, end to end into a temporary folder."""

from __future__ import annotations

import csv
import shutil
import zipfile

import pytest

import agents.evaluation.executors
from agents.cli.main import main, scenario_id
from agents.evaluation.records import RECORD_FIELDS
from agents.training.ppo import pretrained_policy_path

TINY = ["--scenarios", "HeadOn", "--risks", "dr_cvar", "--episodes", "2", "--workers", "1",
        "--no-plots", "--no-progress"]
"""A tiny evaluation: one scenario, one risk, two episodes, in this process."""


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def test_evaluate_writes_csv_summary_and_figures(tmp_path, capsys):
    out = tmp_path / "eval"
    code = main(["evaluate", "--scenarios", "HeadOn", "MultiObstacle", "--risks", "none",
                 "dr_cvar", "--planner", "mpc", "--episodes", "2", "--workers", "1",
                 "--output", str(out), "--no-progress"])
    assert code == 0
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert len(rows) == 2 * 2 * 2
    assert tuple(rows[0]) == RECORD_FIELDS
    summary = (out / "summary.md").read_text()
    assert "obstacle-agnostic MPC" in summary and "safe-nav 0." in summary
    assert "| HeadOn | mpc | dr_cvar | 2 |" in summary
    assert "| MultiObstacle | mpc | none | 2 |" in summary
    assert "## Guarantee audit" in summary and "| MultiObstacle | mpc | dr_cvar | CVaR_α ℓ ≤ δ |" \
        in summary
    for name in ("trajectories_HeadOn.png", "trajectories_MultiObstacle.png",
                 "distance_boxplots.png", "collision_rates.png", "safe_polytopes.png",
                 "episode.gif"):
        assert (out / "figures" / name).stat().st_size > 1000, name
    assert "episodes in" in capsys.readouterr().out


def test_evaluate_with_the_shipped_policy_by_default(tmp_path):
    out = tmp_path / "ppo"
    assert main(["evaluate", "--scenarios", "Overtaking", "--risks", "none", "dr_cvar",
                 "--episodes", "1", "--workers", "1", "--output", str(out), "--no-plots",
                 "--no-progress"]) == 0
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert {r["planner"] for r in rows} == {"ppo"}
    assert all(r["error"] == "" for r in rows)
    sha = rows[0]["policy_sha256"]
    assert len(sha) == 64 and {r["policy_sha256"] for r in rows} == {sha}
    summary = (out / "summary.md").read_text()
    assert str(pretrained_policy_path()) in summary and sha in summary


def test_sweep_writes_its_table_and_plot(tmp_path):
    out = tmp_path / "sweep"
    assert main(["evaluate", "--sweep", "--scenarios", "HeadOn", "--planner", "mpc",
                 "--episodes", "1", "--workers", "1", "--epsilons", "0", "0.1",
                 "--deltas", "0.1", "--output", str(out), "--no-progress"]) == 0
    table = (out / "sweep.md").read_text()
    assert table.count("\n| 0.1 |") == 2
    assert (out / "figures" / "sweep.png").stat().st_size > 1000


def test_reproduce_writes_the_report_and_figures(tmp_path):
    out = tmp_path / "repro"
    assert main(["reproduce", "--episodes", "1", "--workers", "1", "--timing-repeats", "2",
                 "--output", str(out), "--no-progress"]) == 0
    report = (out / "report.md").read_text()
    for heading in ("Example 1", "Table I", "Monte Carlo", "Against the paper"):
        assert heading in report
    assert (out / "figures" / "example1_halfspaces.png").exists()
    assert (out / "figures" / "halfspace_times.png").exists()
    assert (out / "monte_carlo" / "figures" / "distance_boxplots.png").exists()
    assert "b_DR-CVaR = b_CVaR - eps/alpha" in report


@pytest.mark.parametrize(("option", "value"), [
    ("--alpha", "2"), ("--alpha", "0"), ("--alpha", "nan"), ("--delta", "-1"),
    ("--epsilon", "-0.05"), ("--epsilon", "inf"), ("--episodes", "0"), ("--workers", "0"),
    ("--seed", "-1"), ("--noise", "pink"), ("--scenarios", "Roundabout"), ("--risks", "max"),
    ("--epsilons", "-1"), ("--filter-option", "soft"),
])
def test_bad_options_are_rejected_at_parse_time_in_one_line(option, value, tmp_path, capsys):
    code = main(["evaluate", *TINY, "--output", str(tmp_path / "out"), option, value])
    assert code == 2
    line = _one_line(capsys)
    assert line.startswith("safe-nav evaluate: error: argument " + option)
    assert repr(value) in line or value in line
    assert not (tmp_path / "out").exists()  # nothing ran


def test_reproduce_and_bench_options_are_checked_too(capsys):
    assert main(["reproduce", "--episodes", "0"]) == 2
    assert "--episodes" in _one_line(capsys)
    assert main(["bench", "--steps", "-3"]) == 2
    assert "--steps" in _one_line(capsys)


def test_help_shows_defaults_and_units(capsys):
    assert main(["evaluate", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "CVaR tail mass, in (0, 1] (default: 0.2)" in text
    assert "in m (>= 0) (default: 0.1)" in text and "(default: 0.05)" in text
    assert "(default: 300)" in text and "(default: the shipped one)" in text
    for command in ("reproduce", "bench"):
        assert main([command, "--help"]) == 0
        assert "(default:" in capsys.readouterr().out


def test_a_missing_or_corrupt_policy_fails_before_anything_runs(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["evaluate", *TINY, "--policy", str(tmp_path / "missing.zip"),
                 "--output", str(out)]) == 2
    assert "no PPO policy file" in _one_line(capsys)
    not_zip = tmp_path / "policy.zip"
    not_zip.write_bytes(pretrained_policy_path().read_bytes()[:1000])  # truncated
    assert main(["evaluate", *TINY, "--policy", str(not_zip), "--output", str(out)]) == 2
    assert "not a Stable-Baselines3 .zip" in _one_line(capsys)
    other_zip = tmp_path / "other.zip"
    with zipfile.ZipFile(other_zip, "w") as archive:
        archive.writestr("readme.txt", "not a policy")
    assert main(["evaluate", *TINY, "--policy", str(other_zip), "--output", str(out)]) == 2
    assert "cannot load the PPO policy" in _one_line(capsys)
    assert not (out / "episodes.csv").exists()


def test_an_output_path_that_is_a_file_is_refused(tmp_path, capsys):
    target = tmp_path / "results"
    target.write_text("not a folder")
    for output in (target, target / "sub"):
        assert main(["evaluate", *TINY, "--planner", "mpc", "--output", str(output)]) == 2
        assert "is a file" in _one_line(capsys)


def test_a_bad_filter_or_environment_setting_is_one_line(tmp_path, capsys):
    out = str(tmp_path / "out")
    assert main(["evaluate", *TINY, "--planner", "mpc", "--output", out,
                 "--filter-option", "horizon=99"]) == 2
    assert "horizon" in _one_line(capsys)
    assert main(["evaluate", *TINY, "--planner", "mpc", "--output", out,
                 "--filter-option", "bogus=1"]) == 2
    assert "bogus" in _one_line(capsys)
    assert main(["evaluate", *TINY, "--planner", "mpc", "--output", out,
                 "--env-option", "n_samples=0"]) == 2
    assert "n_samples" in _one_line(capsys)


def test_a_failed_episode_exits_1_and_is_run_again_next_time(tmp_path, capsys, monkeypatch):
    from agents.planners import MPCReferencePlanner

    out = tmp_path / "out"
    argv = ["evaluate", *TINY, "--planner", "mpc", "--output", str(out)]
    real = MPCReferencePlanner.predict
    monkeypatch.setattr(MPCReferencePlanner, "predict",
                        lambda *a, **k: (_ for _ in ()).throw(RuntimeError("planner exploded")))
    assert main(argv) == 1
    line = _one_line(capsys)
    assert "2 of 2 episodes failed" in line and "planner exploded" in line
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert len(rows) == 2 and all("planner exploded" in r["error"] for r in rows)
    assert "(2 failed)" in (out / "summary.md").read_text()
    monkeypatch.setattr(MPCReferencePlanner, "predict", real)
    assert main(argv) == 0  # failed rows are never reused: both run again
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert len(rows) == 2 and all(r["error"] == "" for r in rows)


def test_ctrl_c_saves_what_finished_and_the_same_command_resumes(tmp_path, capsys,
                                                                 monkeypatch):
    out = tmp_path / "out"
    argv = ["evaluate", *TINY, "--planner", "mpc", "--episodes", "3", "--output", str(out)]
    real = agents.evaluation.executors.run_spec
    calls = []

    def interrupted_after_two(spec):
        calls.append(spec.seed)
        if len(calls) > 2:
            raise KeyboardInterrupt
        return real(spec)

    monkeypatch.setattr(agents.evaluation.executors, "run_spec", interrupted_after_two)
    assert main(argv) == 130
    line = _one_line(capsys)
    assert "interrupted: 2 of 3 episodes finished" in line and "resume" in line
    assert len(list(csv.DictReader((out / "episodes.csv").open()))) == 2
    monkeypatch.setattr(agents.evaluation.executors, "run_spec", real)
    ran = []
    monkeypatch.setattr(agents.evaluation.executors, "run_spec", lambda spec: ran.append(spec.seed)
                        or real(spec))
    capsys.readouterr()
    assert main(argv) == 0
    assert ran == [2]  # only the missing episode
    assert len(list(csv.DictReader((out / "episodes.csv").open()))) == 3
    assert f"3 episodes (2 reused from {out / 'episodes.csv'}, 1 run now) in" in \
        capsys.readouterr().out


def test_the_cache_refuses_another_policy_and_another_setting(tmp_path, capsys):
    policy = tmp_path / "policy.zip"
    shutil.copy(pretrained_policy_path(), policy)
    out = tmp_path / "out"
    argv = ["evaluate", "--scenarios", "Overtaking", "--risks", "none", "--episodes", "1",
            "--workers", "1", "--no-plots", "--no-progress", "--output", str(out),
            "--policy", str(policy)]
    assert main(argv) == 0
    capsys.readouterr()
    with zipfile.ZipFile(policy, "a") as archive:  # same weights, other bytes
        archive.comment = b"changed"
    assert main(argv) == 2
    line = _one_line(capsys)
    assert "other settings" in line and "policy_sha256" in line and "--overwrite" in line
    assert main([*argv, "--alpha", "0.5"]) == 2
    assert "alpha 0.2 != 0.5" in _one_line(capsys)
    assert main([*argv, "--overwrite"]) == 0
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert len(rows) == 1


def test_scenario_spellings_are_accepted_with_a_note(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["evaluate", *TINY, "--planner", "mpc", "--output", str(out),
                 "--scenarios", "head_on", "SafeNav/Overtaking-v0"]) == 0
    err = capsys.readouterr().err
    assert "'head_on' is called 'HeadOn'" in err
    assert "'SafeNav/Overtaking-v0' is called 'Overtaking'" in err
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert {r["scenario"] for r in rows} == {"HeadOn", "Overtaking"}
    assert scenario_id("head_on") == scenario_id("HeadOn") == "SafeNav/HeadOn-v0"


def test_version_prints_the_package_version(capsys):
    from importlib.metadata import version

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"safe-nav {version('safe-nav')}"


def test_train_saves_under_the_name_given_in_a_new_folder(tmp_path, capsys):
    model = tmp_path / "new" / "folder" / "model"  # no .zip: SB3 would append one
    assert main(["train", "--timesteps", "64", "--n-envs", "1", "--output", str(model),
                 "--quiet", "--no-progress"]) == 0
    assert sorted(p.name for p in model.parent.iterdir()) == ["model", "model.metrics.csv"]
    assert zipfile.is_zipfile(model)
    assert f"saved to {model};" in capsys.readouterr().out


def test_train_output_that_is_a_folder_or_under_a_file_is_one_line(tmp_path, capsys):
    assert main(["train", "--timesteps", "64", "--output", str(tmp_path)]) == 2
    assert "is a folder" in _one_line(capsys)
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["train", "--timesteps", "64", "--output", str(blocker / "model.zip")]) == 2
    assert "is a file" in _one_line(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_the_mpc_planner_with_a_policy_is_an_error(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["evaluate", *TINY, "--planner", "mpc", "--policy",
                 str(pretrained_policy_path()), "--output", str(out)]) == 2
    assert "planner 'mpc'" in _one_line(capsys)
    assert not out.exists()


def test_a_failed_evaluate_leaves_no_empty_folder(tmp_path, capsys):
    out = tmp_path / "new" / "out"
    for extra in (["--filter-option", "bogus=1"], ["--sweep", "--filter-option", "bogus=1"],
                  ["--suite", "stress", "--cases", "biased", "--filter-option", "bogus=1"]):
        argv = ["evaluate", "--episodes", "1", "--workers", "1", "--no-plots", "--no-progress",
                "--planner", "mpc", "--output", str(out), *extra]
        if "--suite" not in extra:
            argv[1:1] = ["--scenarios", "HeadOn", "--risks", "dr_cvar"]
        assert main(argv) == 2
        assert "bogus" in _one_line(capsys)
        assert list(tmp_path.iterdir()) == []


def test_the_custom_scenario_is_usable_from_the_command_line(tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["evaluate", "--scenarios", "Custom", "--risks", "none", "--episodes", "1",
            "--workers", "1", "--no-plots", "--no-progress", "--planner", "mpc",
            "--output", str(out)]
    assert main(argv) == 2
    assert "--env-option scenario=" in _one_line(capsys)
    custom = ('scenario={"name": "mine", "ego_start": [-4, 0], "goal": [4, 0], "obstacles": '
              '[{"start": [2, 0.5], "velocity": [-1, 0]}], "duration": 6}')
    assert main([*argv, "--env-option", 'scenario={"goal": [4, 0]}']) == 2
    assert "missing" in _one_line(capsys)
    assert main([*argv, "--env-option", custom]) == 0
    (row,) = csv.DictReader((out / "episodes.csv").open())
    assert row["scenario"] == "Custom" and row["error"] == ""
    assert '"goal":[4,0]' in row["env_options"]
    assert main(["evaluate", *TINY, "--planner", "mpc", "--output", str(tmp_path / "other"),
                 "--env-option", custom]) == 2  # it would silently replace HeadOn
    assert "for the scenario 'Custom' only" in _one_line(capsys)


def test_ray_without_its_extra_is_one_line_naming_the_extra(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(__import__("sys").modules, "ray", None)  # as if not installed
    code = main(["evaluate", "--executor", "ray", "--scenarios", "HeadOn", "--risks", "none",
                 "--planner", "mpc", "--episodes", "1", "--output", str(tmp_path / "out"),
                 "--no-progress"])
    assert code == 2
    err = capsys.readouterr().err
    assert "'ray' extra" in err and "pip install -e '.[ray]'" in err
    assert "Traceback" not in err


def test_the_filter_flags_build_the_same_config_as_the_python_call():
    from agents.cli.main import _TRAIN_FILTER_FLAGS, build_parser, filter_config
    from filters import FilterConfig

    args = build_parser().parse_args([
        "train", "--filter", "cvar", "--alpha", "0.3", "--epsilon", "auto", "--fallback",
        "brake", "--intervention-penalty", "0.01", "--filter-option", "soft=true",
        "--filter-option", "Q=[[2,0,0,0],[0,2,0,0],[0,0,1,0],[0,0,0,1]]"])
    assert filter_config(args, args.filter, _TRAIN_FILTER_FLAGS) == FilterConfig(
        risk="cvar", alpha=0.3, epsilon="auto", fallback="brake", intervention_penalty=0.01,
        soft=True, Q=[[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    evaluate = build_parser().parse_args(["evaluate"])
    defaults = FilterConfig()
    assert (evaluate.alpha, evaluate.delta, evaluate.epsilon) == (
        defaults.alpha, defaults.delta, defaults.epsilon)


def test_train_filter_flags_need_the_filter(capsys):
    assert main(["train", "--timesteps", "1", "--delta", "0.2", "--fallback", "brake"]) == 2
    assert "--delta, --fallback need --filter" in _one_line(capsys)
    assert main(["train", "--timesteps", "1", "--lambda-lr", "0.1"]) == 2
    assert "--lambda-lr need --lagrangian" in _one_line(capsys)
