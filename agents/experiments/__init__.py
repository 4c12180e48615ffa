"""Experiments built on the evaluation pipeline.

* :mod:`agents.experiments.reproduce` — the paper's figures and tables;
* :mod:`agents.experiments.stress` — the stress suite (cases the paper did not design for);
* :mod:`agents.experiments.audit` — empirical checks of each risk's guarantee;
* :mod:`agents.experiments.pareto` — safety against cost frontiers;
* :mod:`agents.experiments.goal_reaching` — does a planner reach its goal from
  where a filter leaves it.
"""
