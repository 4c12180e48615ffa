"""Example 1 (Fig. 2) and the halfspace timing figure (Fig. 3) of ``safe-nav reproduce``.

The Example 1 setup and the Table I timing itself are in
:mod:`agents.experiments.table_one`; this module computes Example 1's halfspaces and
draws both figures.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agents.evaluation.plots import arena_axes, pyplot, save_figure
from agents.experiments.table_one import EXAMPLE_ONE
from filters.plotting import draw_halfspace


def example_one(seed: int = 0) -> dict:
    """Example 1: halfspaces of every metric for the paper's setup.

    Returns a dict with the samples, the normal and, per label, the offset ``b``
    and whether the ego reference lies on the safe side.
    """
    from filters import Disc, safe_halfspaces

    rng = np.random.default_rng(seed)
    e = EXAMPLE_ONE
    samples = rng.multivariate_normal(e["obstacle"], e["variance"] * np.eye(2), e["n_samples"])
    reference = np.asarray(e["reference"], dtype=float)[None, :]
    samples4 = samples[None, :, None, :]
    shapes = dict(ego_shape=Disc(e["radius"]), obstacle_shapes=[Disc(e["radius"])])
    cases = [("mean", "mean", 0.0), ("CVaR", "cvar", 0.0)] + [
        (f"DR-CVaR eps={eps:g}", "dr_cvar", eps) for eps in e["epsilons"]]
    result = {"samples": samples, "reference": reference[0], "halfspaces": {}}
    for label, risk, eps in cases:
        hs = safe_halfspaces(reference, samples4, risk=risk, alpha=e["alpha"], delta=e["delta"],
                             epsilon=eps, **shapes)
        normal, offset = hs.normals[0, 0], float(hs.offsets[0, 0])
        result["normal"] = normal
        result["halfspaces"][label] = {
            "offset": offset, "reference_safe": bool(normal @ reference[0] <= offset)}
    return result


def plot_example_one(example: dict, path: Path) -> Path:
    """Fig. 2: the samples, the reference and every halfspace boundary."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 5))
    arena_axes(ax, ((-2.0, -1.8), (1.5, 1.2)))
    samples = example["samples"]
    ax.scatter(samples[:, 0], samples[:, 1], s=4, color="k", alpha=0.5,
               label="predicted obstacle positions (samples)")
    ax.add_patch(plt.Circle(EXAMPLE_ONE["obstacle"], EXAMPLE_ONE["radius"], color="k",
                            alpha=0.2, label=f"obstacle disc, r = {EXAMPLE_ONE['radius']:g} m"))
    ax.add_patch(plt.Circle(example["reference"], EXAMPLE_ONE["radius"], color="tab:blue",
                            alpha=0.3, label=f"ego disc, r = {EXAMPLE_ONE['radius']:g} m"))
    ax.plot(*example["reference"], "bo", label="ego reference position")
    ax.annotate("", xy=example["reference"] + 0.5 * example["normal"],
                xytext=example["reference"], arrowprops=dict(arrowstyle="->"))
    ax.plot([], [], color="k", marker=r"$\rightarrow$", ls="", ms=12,
            label="normal h (ego towards the sample mean)")
    colors = {"mean": "tab:red", "CVaR": "tab:blue"}
    greens = iter(["#66c266", "#2e9e2e", "#145214"])
    for label, data in example["halfspaces"].items():
        draw_halfspace(ax, example["normal"], data["offset"],
                       color=colors.get(label) or next(greens), alpha=0.9, label=label)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              title="boundary h·y = b of each risk\n(safe side: below-left)", title_fontsize=7)
    ax.set_title("Example 1 (Fig. 2): safe halfspaces of mean, CVaR and DR-CVaR\n"
                 f"α = {EXAMPLE_ONE['alpha']:g}, δ = {EXAMPLE_ONE['delta']:g} m, "
                 f"{EXAMPLE_ONE['n_samples']} samples of N(p, {EXAMPLE_ONE['variance']:g} I)",
                 fontsize=10)
    return save_figure(fig, path)


def plot_halfspace_times(table: dict, path: Path) -> Path:
    """Fig. 3: CVXPY setup/solve/call and our time per halfspace against N_s (log scale)."""
    fig, ax = pyplot().subplots(figsize=(6, 4))
    counts = sorted(table["cvxpy"]["dr_cvar"])
    for key, style in (("setup", ":"), ("solve", "--"), ("call", "-")):
        ax.plot(counts, [table["cvxpy"]["dr_cvar"][n][key] for n in counts], style + "o",
                color="tab:green", label=f"DR-CVaR CVXPY {key}")
    ax.plot(counts, [table["cvxpy"]["cvar"][n]["call"] for n in counts], "-s", color="tab:blue",
            label="CVaR CVXPY call")
    ax.plot(counts, [table["ours"][n] for n in counts], "-^", color="k",
            label="ours (closed form), per halfspace")
    ax.set(xscale="log", yscale="log", xlabel="number of samples N_s", ylabel="time (ms)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    return save_figure(fig, path)
