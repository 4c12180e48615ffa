"""Experiments built on the evaluation pipeline.

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
