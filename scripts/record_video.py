"""Record one filtered episode with Gymnasium's ``RecordVideo`` (an mp4, optionally a GIF).

The planner is a PPO policy (the shipped one by default) behind
:class:`filters.SafetyFilterWrapper` with the roll-out reference (the policy rolled
out over the horizon on the obstacles' predicted mean motion, the evaluation's
default). The wrapper draws each obstacle's first-step safe halfspace through the
renderer's hooks (line and shaded safe side), so the clip shows what the filter
enforced at every step. Everything is seeded: the same options give the same frames.
The clip in ``docs/figures`` was made with::

    python scripts/record_video.py --scenario RandomCrossing --seed 2 --gif \\
        --output docs/figures

``RecordVideo`` needs moviepy: ``pip install -e '.[video]'`` (not in the default set-up).
GitHub shows a GIF inline in a README but not a committed mp4; ``--gif`` writes the
same frames as a GIF (:func:`agents.evaluation.plots.save_gif`) next to the mp4.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

DEFAULT_SCENARIO = "RandomCrossing"
DEFAULT_RISK = "dr_cvar"


@dataclass(frozen=True)
class Recording:
    """What :func:`record_episode` wrote and what happened in the episode.

    Attributes
    ----------
    video
        The mp4 written by ``RecordVideo``.
    gif
        The GIF of the same frames, or ``None``.
    frames
        Frames in the clip: the reset frame and one per step (``steps + 1``).
    steps
        Environment steps of the episode.
    fps
        Frames per second of the clip (the environment's ``render_fps``: real time).
    reached_goal, collided
        Whether the ego reached the goal; any continuous-time collision on the way
        (:class:`agents.evaluation.runner.EpisodeStats`, as in the evaluation's records).
    mean_intervention
        Mean ``||u_safe - u_ref||`` over the steps, in m/s².
    """

    video: Path
    gif: Path | None
    frames: int
    steps: int
    fps: int
    reached_goal: bool
    collided: bool
    mean_intervention: float


def record_episode(
    output: str | Path,
    *,
    scenario: str = DEFAULT_SCENARIO,
    risk: str = DEFAULT_RISK,
    seed: int = 0,
    policy_path: str | Path = "",
    name: str | None = None,
    gif: bool = False,
    max_steps: int | None = None,
) -> Recording:
    """Run one seeded episode of a filtered PPO policy and record it with ``RecordVideo``.

    Parameters
    ----------
    output
        Folder for the clip (created if missing).
    scenario
        A scenario name (``"RandomCrossing"``, ``"MultiObstacle"``, ...).
    risk
        The filter's risk metric (:data:`filters.wrapper.RISKS`); ``"none"`` records
        the unfiltered policy (no halfspaces drawn).
    seed
        Seed of ``env.reset``: obstacles, noise and any random scenario data.
    policy_path
        A PPO ``.zip``; empty for the policy shipped with the package.
    name
        File stem; default ``"<scenario>_<risk>_seed<seed>"``. The clip is
        ``<output>/<name>.mp4`` (and ``.gif``).
    gif
        Also write the frames as ``<name>.gif`` (GitHub inlines GIFs, not mp4s).
    max_steps
        Stop after this many steps (>= 1) if the episode has not ended; ``None``: the
        whole episode.

    Returns
    -------
    Recording

    Raises
    ------
    InvalidParameterError
        If the scenario, risk, seed or ``max_steps`` is invalid.
    PolicyFileError
        If the policy does not load.
    gymnasium.error.DependencyNotInstalled
        If moviepy is missing.
    """
    import gymnasium as gym

    from agents.evaluation.plots import RISK_LABELS, save_gif
    from agents.evaluation.records import EpisodeSpec
    from agents.evaluation.runner import EpisodeStats, make_env
    from filters._validation import integer_at_least

    if max_steps is not None:
        integer_at_least("max_steps", max_steps)
    spec = EpisodeSpec(scenario=scenario, risk=risk, seed=seed, planner="ppo",
                       reference="rollout", policy_path=str(policy_path))
    stem, folder = name or f"{spec.scenario}_{spec.risk}_seed{spec.seed}", Path(output)
    env, planner = make_env(spec, render_mode="rgb_array")
    try:
        with warnings.catch_warnings():  # the folder may hold other files (docs/figures)
            warnings.filterwarnings("ignore", message=".*Overwriting existing videos")
            video = gym.wrappers.RecordVideo(env, str(folder), name_prefix=stem,
                                             episode_trigger=lambda episode: True,
                                             disable_logger=True)
    except BaseException:
        env.close()
        raise
    stats = EpisodeStats()  # the evaluation's own per-episode bookkeeping
    with video:  # RecordVideo writes the clip on close()
        obs, info = video.reset(seed=int(spec.seed))
        stats.start(env.unwrapped, info)
        done = False
        while not done:
            obs, reward, terminated, truncated, info = video.step(
                planner.predict(obs, deterministic=True)[0])
            stats.step(env.unwrapped, reward, info)
            done = terminated or truncated or stats.steps == max_steps
        frames, fps = list(video.recorded_frames), int(video.frames_per_sec)
    episode = stats.summary()
    path = (folder / f"{stem}-episode-0.mp4").replace(folder / f"{stem}.mp4")
    label = (f"{spec.scenario}, seed {spec.seed}, PPO + "
             f"{RISK_LABELS.get(spec.risk, spec.risk)} filter")
    return Recording(path, save_gif(frames, folder / f"{stem}.gif", fps=fps, label=label)
                     if gif else None, len(frames), episode["steps"], fps,
                     episode["goal_reached"], episode["collision"], episode["mean_intervention"])


def main(argv: list[str] | None = None) -> int:
    from gymnasium.error import DependencyNotInstalled

    from agents.errors import PolicyFileError
    from filters.errors import InvalidParameterError

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add = parser.add_argument
    add("--scenario", default=DEFAULT_SCENARIO)
    add("--risk", default=DEFAULT_RISK, help="filter risk metric ('none': the unfiltered policy)")
    add("--seed", type=int, default=0)
    add("--policy", default="", help="PPO .zip (default: the shipped policy)")
    add("--output", default="videos", help="folder for the clip")
    add("--name", default=None, help="file stem (default: scenario_risk_seedN)")
    add("--gif", action="store_true", help="also write the frames as a GIF")
    add("--max-steps", type=int, default=None)
    args = parser.parse_args(argv)
    try:
        rec = record_episode(args.output, scenario=args.scenario, risk=args.risk,
                             seed=args.seed, policy_path=args.policy, name=args.name,
                             gif=args.gif, max_steps=args.max_steps)
    except (InvalidParameterError, PolicyFileError) as exc:
        print(f"record_video: error: {exc}", file=sys.stderr)
        return 2
    except (ImportError, DependencyNotInstalled) as exc:  # moviepy missing
        print(f"record_video: error: RecordVideo needs moviepy, which is in the 'video' "
              f"extra: pip install -e '.[video]' ({exc})", file=sys.stderr)
        return 2
    outcome = "collision" if rec.collided else ("goal" if rec.reached_goal else "no goal")
    print(f"{rec.video} ({rec.video.stat().st_size / 1e3:.0f} kB, {rec.frames} frames at "
          f"{rec.fps} fps): {rec.steps} steps, {outcome}, mean intervention "
          f"{rec.mean_intervention:.2f} m/s^2")
    if rec.gif is not None:
        print(f"{rec.gif} ({rec.gif.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
