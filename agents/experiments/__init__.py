"""Experiments built on the evaluation pipeline.

The stress, crowd and pedestrian suites are campaigns: they build their episode specs
and run them with :func:`agents.evaluation.campaign.run_campaign` under an
:class:`~agents.evaluation.config.EvaluationConfig`. The paper's Monte Carlo
(:mod:`~agents.experiments.encounters`) needs each episode's trajectory and the
preset's planner: it runs the same runner (:func:`agents.evaluation.runner.run_episode`)
on the same executors (:mod:`agents.evaluation.executors`), with its own task per
episode (:func:`~agents.experiments.encounters.run_encounter`).

* :mod:`agents.experiments.reproduce` — the paper's figures and tables;
  its parts: :mod:`~agents.experiments.paper_settings` (the paper's numbers and the
  presets), :mod:`~agents.experiments.encounters` (the Monte Carlo episodes),
  :mod:`~agents.experiments.windows` (statistics windows and their summary) and
  :mod:`~agents.experiments.paper_figures` (Example 1, Fig. 3);
* :mod:`agents.experiments.stress` — the stress suite (cases the paper did not design for);
* :mod:`agents.experiments.table_one` — the paper's Table I timing (CVXPY against ours);
* :mod:`agents.experiments.pareto` — safety against cost frontiers;
* :mod:`agents.experiments.goal_reaching` — does a planner reach its goal from
  where a filter leaves it.
"""
