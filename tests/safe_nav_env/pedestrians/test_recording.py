"""Recorded pedestrian files: parsing, errors naming the line, resampling inside spans only."""

from __future__ import annotations

import numpy as np
import pytest

from safe_nav_env.errors import ConfigError, ScenarioError
from safe_nav_env.pedestrians.recording import (
    SCENES,
    RecordingError,
    load_recording,
    parse_tracks,
    resample,
    scene_path,
)


@pytest.mark.parametrize("scene", list(SCENES))
def test_packaged_scene_loads_with_every_pedestrian_inside_its_span(scene):
    raw = np.loadtxt(scene_path(scene))
    rec = load_recording(scene)
    assert rec.name == scene and rec.dt == 0.2
    assert rec.n_pedestrians == np.unique(raw[:, 1]).shape[0]
    steps = np.arange(rec.n_steps)[:, None]
    inside = (steps >= rec.first) & (steps <= rec.last)
    assert np.array_equal(~np.isnan(rec.positions[..., 0]), inside)
    assert np.isfinite(rec.positions[inside]).all()
    # Every raw observation on the grid (frames every 10 = 0.4 s = 2 steps) is kept exactly.
    frames = raw[:, 0] - raw[:, 0].min()
    on_grid = np.isclose(frames * 0.04 / 0.2, np.round(frames * 0.04 / 0.2))
    ped = np.searchsorted(rec.ids, raw[on_grid, 1])
    step = np.round(frames[on_grid] * 0.04 / 0.2).astype(int)
    assert np.allclose(rec.positions[step, ped], raw[on_grid, 2:])


def test_interpolation_fills_gaps_inside_a_span_and_never_extrapolates():
    text = "\n".join([
        "0\t1\t0.0\t0.0",
        "10\t1\t0.4\t0.0",  # 0.4 s later
        "30\t1\t0.4\t1.6",  # after a gap of one frame (0.8 s)
        "10\t2\t5.0\t5.0",
        "20\t2\t5.0\t6.0",
    ])
    rec = resample(parse_tracks(text), dt=0.2, name="tiny")
    one, two = (int(np.searchsorted(rec.ids, i)) for i in (1.0, 2.0))
    assert rec.n_steps == 7  # 0 .. 1.2 s
    assert np.allclose(rec.positions[:, one], [[0.0, 0.0], [0.2, 0.0], [0.4, 0.0], [0.4, 0.4],
                                               [0.4, 0.8], [0.4, 1.2], [0.4, 1.6]])
    assert (rec.first[two], rec.last[two]) == (2, 4)
    assert np.isnan(rec.positions[[0, 1, 5, 6], two]).all()  # before its first, after its last
    assert np.allclose(rec.positions[2:5, two], [[5.0, 5.0], [5.0, 5.5], [5.0, 6.0]])


@pytest.mark.parametrize(
    ("bad_line", "reason"),
    [
        ("20\t1\t0.5", "expected 4"),
        ("20\t1\t0.5\tfoo", "expected 4"),
        ("20\t1\t0.5\t1.0\t7", "expected 4"),
        ("20\t1\tnan\t1.0", "finite"),
        ("10\t1\t9.0\t9.0", "already observed"),
    ],
)
def test_malformed_line_is_named_with_its_number_and_text(tmp_path, bad_line, reason):
    path = tmp_path / "scene.txt"
    path.write_text("0\t1\t0.0\t0.0\n10\t1\t0.4\t0.0\n\n" + bad_line + "\n30\t1\t1.0\t0.0\n")
    with pytest.raises(RecordingError) as caught:
        load_recording(path)
    message = str(caught.value)
    assert str(path) in message and "line 4" in message and repr(bad_line) in message
    assert reason in message
    assert isinstance(caught.value, ScenarioError) and isinstance(caught.value, ValueError)


@pytest.mark.parametrize("content", ["", "\n\n  \n"])
def test_empty_file_is_an_error(tmp_path, content):
    path = tmp_path / "empty.txt"
    path.write_text(content)
    with pytest.raises(RecordingError, match="empty"):
        load_recording(path)


def test_unknown_scene_or_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="eth"):
        load_recording("nowhere")
    with pytest.raises(ConfigError, match="neither"):
        load_recording(tmp_path / "missing.txt")


def test_walkable_box_lies_inside_the_bounding_box():
    rec = load_recording("hotel")
    (x0, y0), (x1, y1) = rec.walkable_box()
    raw = np.loadtxt(scene_path("hotel"))
    assert raw[:, 2].min() < x0 < x1 < raw[:, 2].max()
    assert raw[:, 3].min() < y0 < y1 < raw[:, 3].max()
