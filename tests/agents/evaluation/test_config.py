"""EvaluationConfig: checked once when made, errors that name the value; split_options."""

from pathlib import Path

import pytest

from agents.errors import OutputPathError
from agents.evaluation.campaign import run_evaluation
from agents.evaluation.config import EvaluationConfig, split_options
from agents.evaluation.executors import SerialExecutor
from filters.errors import InvalidParameterError


@pytest.mark.parametrize(("kwargs", "message"), [
    (dict(workers=0), "workers must be an integer >= 1, got 0"),
    (dict(workers=True), "workers must be an integer >= 1, got True"),
    (dict(workers=1.5), "workers must be an integer >= 1, got 1.5"),
    (dict(executor="threads"), "executor must be one of ('process', 'ray') or an Executor, "
                               "got 'threads'"),
    (dict(address="head:6379"), "a Ray address ('head:6379') needs executor='ray'"),
    (dict(executor="ray", address=" "), "address must be HOST:PORT or 'auto', got ' '"),
    (dict(plots="no"), "plots must be True or False, got 'no'"),
    (dict(overwrite=1), "overwrite must be True or False, got 1"),
    (dict(output=3), "output must be a folder path, got 3"),
])
def test_a_bad_value_is_named_in_the_error(kwargs, message):
    with pytest.raises(InvalidParameterError) as info:
        EvaluationConfig(**kwargs)
    assert message in str(info.value)
    assert isinstance(info.value, ValueError)


def test_an_output_under_a_file_is_refused_when_the_config_is_made(tmp_path):
    (tmp_path / "taken").write_text("")
    with pytest.raises(OutputPathError, match="taken is a file"):
        EvaluationConfig(output=tmp_path / "taken" / "run")
    assert not (tmp_path / "new").exists()
    assert EvaluationConfig(output=str(tmp_path / "new")).output == tmp_path / "new"
    assert not (tmp_path / "new").exists()  # made by the first file written, not here


def test_a_config_is_frozen_and_replace_checks_again():
    from dataclasses import FrozenInstanceError, replace

    config = EvaluationConfig(workers=1)
    with pytest.raises(FrozenInstanceError):
        config.workers = 2
    with pytest.raises(InvalidParameterError, match="got -1"):
        replace(config, workers=-1)


def test_split_options_separates_how_from_what():
    config, settings = split_options(EvaluationConfig(workers=1, plots=False), None,
                                     dict(progress=False, planner="mpc", alpha=0.1,
                                          filter_options=None), default="results/x")
    assert config == EvaluationConfig(output=Path("results/x"), workers=1, plots=False,
                                      progress=False)
    assert settings == dict(planner="mpc", alpha=0.1, filter_options="")
    # An output given next to the config wins; the config's own wins over the default.
    assert split_options(config, "elsewhere", {}, default="d")[0].output == Path("elsewhere")
    assert split_options(config, None, {}, default="d")[0].output == Path("results/x")


@pytest.mark.parametrize(("options", "fixed", "message"), [
    (dict(wokers=2), (), "unknown option(s) ['wokers']"),
    (dict(delta=0.1), ("delta", "epsilon"), "this campaign sets ['delta'] itself"),
    (dict(workers=0), (), "workers must be an integer >= 1, got 0"),
])
def test_split_options_rejects_what_it_cannot_place(options, fixed, message):
    with pytest.raises(InvalidParameterError) as info:
        split_options(None, None, options, default="d", fixed=fixed)
    assert message in str(info.value)


def test_a_campaign_runs_on_the_configs_executor_and_writes_into_its_output(tmp_path):
    class Counting(SerialExecutor):
        ran = 0

        def run(self, specs):
            for record in super().run(specs):
                Counting.ran += 1
                yield record

    config = EvaluationConfig(output=tmp_path / "out", executor=Counting(), plots=False,
                              progress=False)
    outputs = run_evaluation(None, ["HeadOn"], ["none"], config=config, episodes=2,
                             planner="mpc")
    assert Counting.ran == 2 and len(outputs.records) == 2
    assert outputs.files["episodes"] == tmp_path / "out" / "episodes.csv"
    assert (tmp_path / "out" / "summary.md").exists()
    assert not (tmp_path / "out" / "figures").exists()
