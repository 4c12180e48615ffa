"""How a campaign runs: :class:`EvaluationConfig`, one value for every evaluation command.

The settings here decide *how* episodes run and *where* their results go (executor,
workers, output folder, resume or overwrite, figures, progress bar), never *what* an
episode gives: two runs of the same episode specs under any two configs write the same
rows (timing columns aside). What runs is the campaign's list of
:class:`~agents.evaluation.records.EpisodeSpec`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from agents.evaluation.evaluate import SPEC_OPTIONS, output_folder
from agents.evaluation.executors import EXECUTORS, Executor
from filters._validation import integer_at_least
from filters.errors import InvalidParameterError

__all__ = ["EvaluationConfig", "split_options"]


@dataclass(frozen=True)
class EvaluationConfig:
    """The how-to-run settings of an evaluation, checked once when made.

    Attributes
    ----------
    output
        Output folder (CSV, run key, summary, figures), or ``None``: the campaign's own
        default (``results/evaluate``, ``results/stress``, ...). It is made by the first
        file written into it, so a run failing before that leaves no empty folder.
    workers
        Local worker processes (>= 1; 1 runs in this process).
    executor
        ``"process"`` (local processes), ``"ray"``, or an
        :class:`~agents.evaluation.executors.Executor` to reuse (left open afterwards).
    address
        ``--executor ray``: the cluster, ``"HOST:PORT"`` or ``"auto"``; ``None``: Ray's own
        default (``RAY_ADDRESS``, else a local Ray).
    overwrite
        Discard the results already in ``output`` instead of resuming from them.
    plots
        Write the campaign's figures.
    progress
        Show a progress bar.

    Raises
    ------
    InvalidParameterError
        For a value of the wrong type or range, naming it.
    OutputPathError
        If ``output`` or one of its parents is a file.
    """

    output: Path | None = None
    workers: int = 2
    executor: str | Executor = "process"
    address: str | None = None
    overwrite: bool = False
    plots: bool = True
    progress: bool = True

    def __post_init__(self) -> None:
        if self.output is not None:
            if not isinstance(self.output, (str, Path)):
                raise InvalidParameterError(f"output must be a folder path, got {self.output!r}")
            object.__setattr__(self, "output", output_folder(self.output))
        object.__setattr__(self, "workers", integer_at_least("workers", self.workers, low=1))
        if not isinstance(self.executor, Executor) and self.executor not in EXECUTORS:
            raise InvalidParameterError(f"executor must be one of {EXECUTORS} or an Executor, "
                                        f"got {self.executor!r}")
        if self.address is not None:
            if not isinstance(self.address, str) or not self.address.strip():
                raise InvalidParameterError(f"address must be HOST:PORT or 'auto', got "
                                            f"{self.address!r}")
            if self.executor != "ray":
                raise InvalidParameterError(f"a Ray address ({self.address!r}) needs "
                                            "executor='ray' (--executor ray); an Executor "
                                            "instance carries its own")
        for name in ("overwrite", "plots", "progress"):
            if not isinstance(getattr(self, name), bool):
                raise InvalidParameterError(f"{name} must be True or False, got "
                                            f"{getattr(self, name)!r}")


def split_options(config: EvaluationConfig | None, output: str | Path | None,
                  options: Mapping[str, Any], *, default: str,
                  fixed: Sequence[str] = ()) -> tuple[EvaluationConfig, dict[str, Any]]:
    """Split a campaign's keywords into its config and its episodes' settings.

    Parameters
    ----------
    config
        The caller's config, or ``None`` for the defaults.
    output
        An output folder given next to ``config`` (it wins), or ``None``.
    options
        Fields of :class:`EvaluationConfig` (they override ``config``) and fields of
        :class:`~agents.evaluation.records.EpisodeSpec` shared by every episode
        (``planner``, ``alpha``, ``filter_options``, ...; ``None`` options mean none).
    default
        The campaign's output folder where neither ``output`` nor ``config`` gives one.
    fixed
        Episode settings the campaign sets itself (given here: an error).

    Returns
    -------
    tuple
        The config (its output set) and the episode settings.

    Raises
    ------
    InvalidParameterError
        For a keyword that is neither, one in ``fixed``, or a bad config value.
    """
    run = {name: value for name, value in options.items() if name in CONFIG_FIELDS}
    settings = {name: value for name, value in options.items() if name not in run}
    if unknown := sorted(set(settings) - set(SPEC_OPTIONS)):
        raise InvalidParameterError(f"unknown option(s) {unknown}; expected some of "
                                    f"{sorted(CONFIG_FIELDS)} or {list(SPEC_OPTIONS)}")
    if given := [name for name in fixed if name in settings]:
        raise InvalidParameterError(f"this campaign sets {given} itself; drop them")
    for name in ("filter_options", "env_options"):
        if name in settings and settings[name] is None:
            settings[name] = ""
    config = replace(config or EvaluationConfig(), **run)
    output = output if output is not None else config.output or default
    return replace(config, output=output), settings


CONFIG_FIELDS = frozenset(f.name for f in fields(EvaluationConfig))
"""The names of :class:`EvaluationConfig`'s fields."""
