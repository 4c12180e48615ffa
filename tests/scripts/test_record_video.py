"""scripts/record_video.py: a RecordVideo clip of a filtered PPO episode."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from agents.errors import PolicyFileError
from filters.errors import InvalidParameterError

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "record_video.py"


def _script():
    """The script as a module (``scripts`` is not a package)."""
    if "record_video" not in sys.modules:
        spec = importlib.util.spec_from_file_location("record_video", SCRIPT)
        module = importlib.util.module_from_spec(spec)
        sys.modules["record_video"] = module  # dataclasses look their module up
        spec.loader.exec_module(module)
    return sys.modules["record_video"]


def _decoded_frames(path: Path) -> tuple[list[np.ndarray], float]:
    from moviepy import VideoFileClip

    clip = VideoFileClip(str(path))
    try:
        return [np.asarray(f) for f in clip.iter_frames()], float(clip.fps)
    finally:
        clip.close()


@pytest.mark.video  # the video extra: pytest -m video
@pytest.mark.slow  # loads torch and runs ffmpeg: ~10 s of CPU
def test_records_a_short_filtered_episode(tmp_path):
    import moviepy  # noqa: F401
    from PIL import Image

    from agents.evaluation.records import EpisodeSpec
    from agents.evaluation.runner import make_env

    record_video = _script()
    rec = record_video.record_episode(tmp_path / "clips", scenario="RandomCrossing", seed=1,
                                      max_steps=8, gif=True)
    assert rec.video == tmp_path / "clips" / "RandomCrossing_dr_cvar_seed1.mp4"
    assert sorted(p.name for p in rec.video.parent.iterdir()) == [
        "RandomCrossing_dr_cvar_seed1.gif", "RandomCrossing_dr_cvar_seed1.mp4"]
    assert rec.steps == 8 and rec.frames == 9  # the reset frame and one per step
    # the filter first acts at step 6 of this seed (0.14-0.25 m/s^2 at steps 6-8)
    assert rec.fps == 5 and not rec.collided and rec.mean_intervention > 0.05
    assert 1_000 < rec.video.stat().st_size < 1_000_000

    frames, fps = _decoded_frames(rec.video)
    assert fps == 5.0 and len(frames) == rec.frames
    assert all(f.shape == (600, 600, 3) and f.dtype == np.uint8 for f in frames)
    # The clip's first frame is the environment's own reset frame (up to H.264 loss),
    # with the filter's render hook installed; a frame of another seed is far off.
    spec = EpisodeSpec(scenario="RandomCrossing", risk="dr_cvar", seed=1)
    env, _ = make_env(spec, render_mode="rgb_array")
    try:
        env.reset(seed=1)
        reference = env.render().astype(float)
        env.reset(seed=2)
        other = env.render().astype(float)
    finally:
        env.close()
    first = frames[0].astype(float)
    assert np.abs(first - reference).mean() < 1.0  # measured 0.23 (8-bit levels)
    assert np.abs(first - other).mean() > 2.0  # measured 3.2
    assert np.abs(frames[1].astype(float) - reference).mean() > 2.0  # the ego moved
    with Image.open(rec.gif) as gif:
        assert gif.n_frames == rec.frames


def test_rejects_bad_options(tmp_path):
    record_video = _script()
    with pytest.raises(InvalidParameterError, match="max_steps"):
        record_video.record_episode(tmp_path, max_steps=0)
    with pytest.raises(InvalidParameterError, match="risk"):
        record_video.record_episode(tmp_path, risk="cvarr")
    with pytest.raises(PolicyFileError):
        record_video.record_episode(tmp_path, policy_path=tmp_path / "missing.zip")
    assert not any(tmp_path.iterdir())


def test_main_reports_errors_with_exit_code_2(tmp_path, capsys):
    record_video = _script()
    assert record_video.main(["--output", str(tmp_path), "--max-steps", "0"]) == 2
    assert "max_steps" in capsys.readouterr().err
