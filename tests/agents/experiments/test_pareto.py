"""Pareto plots: the data-in API, dominance, and a PNG written."""

from __future__ import annotations

import math

import pytest

from agents.experiments.pareto import ParetoPoint, dominated, plot_pareto
from filters.errors import InvalidParameterError


def test_dominance_by_hand():
    points = [ParetoPoint("a", 10, 100, 3.0),   # dominated by b (fewer collisions, faster)
              ParetoPoint("b", 5, 100, 2.5),
              ParetoPoint("c", 0, 100, 4.0),    # safest: not dominated
              ParetoPoint("d", 5, 100, 2.5),    # ties b: not dominated
              ParetoPoint("e", 50, 100, math.nan)]  # never reached the goal
    assert dominated(points) == [True, False, False, False, False]
    assert points[1].rate == 0.05


def test_point_validation():
    with pytest.raises(InvalidParameterError, match="collisions <= n"):
        ParetoPoint("x", 3, 2, 1.0)
    with pytest.raises(InvalidParameterError, match="n >= 1"):
        ParetoPoint("x", 0, 0, 1.0)
    with pytest.raises(InvalidParameterError, match="time_to_goal"):
        ParetoPoint("x", 0, 1, -1.0)
    with pytest.raises(InvalidParameterError, match="collisions must be an integer"):
        ParetoPoint("x", 0.5, 1, 1.0)


def test_plot_pareto_writes_a_png(tmp_path):
    panels = {"heavy_tail": [ParetoPoint("none (unfiltered)", 180, 200, 2.2),
                             ParetoPoint("dr_cvar (eps=auto)", 2, 200, 2.6)],
              "crossing5": [ParetoPoint("none (unfiltered)", 200, 200, 3.0),
                            ParetoPoint("conformal", 0, 200, math.nan)],
              "biased": [ParetoPoint("cvar", 3, 200, 2.4)]}
    path = plot_pareto(panels, tmp_path / "figs" / "pareto.png", columns=2)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert path.stat().st_size > 5000


def test_plot_pareto_rejects_empty_input(tmp_path):
    with pytest.raises(InvalidParameterError, match="at least one panel"):
        plot_pareto({}, tmp_path / "x.png")
    with pytest.raises(InvalidParameterError, match="no points"):
        plot_pareto({"a": []}, tmp_path / "x.png")
