"""The evaluate command builds one EvaluationConfig from its flags and hands it to a campaign."""

from pathlib import Path

import pytest

from agents.cli.main import main
from agents.evaluation.campaign import EvaluationOutputs
from agents.evaluation.config import EvaluationConfig


@pytest.fixture
def calls(monkeypatch):
    """The campaign functions, replaced by ones that record their arguments."""
    seen = {}

    def fake(name):
        def run(output, *args, config, **kwargs):
            seen.update(name=name, output=output, args=args, config=config, kwargs=kwargs)
            return EvaluationOutputs([], [], "table\n", 0.0)
        return run

    import agents.evaluation.campaign as campaign
    import agents.experiments.crowd as crowd
    import agents.experiments.pedestrians as pedestrians
    import agents.experiments.stress as stress

    for module, name in ((campaign, "run_evaluation"), (campaign, "run_sweep"),
                         (stress, "run_stress"), (crowd, "run_crowd"),
                         (pedestrians, "run_pedestrians")):
        monkeypatch.setattr(module, name, fake(name))
    return seen


@pytest.mark.parametrize(("argv", "name", "output"), [
    ([], "run_evaluation", "results/evaluate"),
    (["--sweep"], "run_sweep", "results/evaluate"),
    (["--suite", "stress"], "run_stress", "results/stress"),
    (["--suite", "crowd"], "run_crowd", "results/crowd"),
    (["--suite", "pedestrians"], "run_pedestrians", "results/pedestrians"),
    (["--suite", "crowd", "--output", "mine"], "run_crowd", "mine"),
])
def test_every_campaign_gets_the_same_config(calls, argv, name, output):
    assert main(["evaluate", *argv, "--workers", "1", "--no-plots", "--overwrite",
                 "--no-progress", "--episodes", "3", "--seed", "5"]) == 0
    assert calls["name"] == name and calls["output"] is None
    config = calls["config"]
    assert isinstance(config, EvaluationConfig)
    assert config.output == Path(output)
    assert (config.workers, config.overwrite, config.plots, config.progress) == (
        1, True, False, False)
    assert (config.executor, config.address) == ("process", None)
    assert (calls["kwargs"]["episodes"], calls["kwargs"]["seed"]) == (3, 5)


def test_the_executor_flags_go_into_the_config(calls):
    assert main(["evaluate", "--executor", "ray", "--address", "head:6379",
                 "--no-progress"]) == 0
    assert (calls["config"].executor, calls["config"].address) == ("ray", "head:6379")


def test_an_address_without_ray_is_one_line_and_exit_code_2(calls, capsys):
    assert main(["evaluate", "--address", "head:6379", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a Ray address ('head:6379') needs" in err
    assert "name" not in calls  # refused before any campaign started
