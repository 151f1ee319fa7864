"""Watching an evaluation (``ilcsan evaluate``): episode videos with every frame, the episodes unchanged, nothing
half-written, and progress on long evaluations."""

from __future__ import annotations

import gc
import os
import re
import sys

import numpy as np
import pytest
from test_policy_cli import assert_one_line_error, run_cli

import ilcsan
from ilcsan.errors import UserError
from ilcsan.rl.evaluation import evaluate_policy, run_episodes
from ilcsan.rl.tasks import RENDERING_FIX, make_env
from ilcsan.rl.video import EpisodeVideo


@pytest.fixture(autouse=True)
def _environment_restored():
    """Recording picks rendering back-ends through environment variables; other tests see the environment as it was."""
    saved = dict(os.environ)
    yield
    os.environ.clear()
    os.environ.update(saved)


def read_video(path):
    """(frames, frame rate, (width, height)) of an MP4 file, decoded by ffmpeg."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    frames = [np.frombuffer(frame, np.uint8).reshape(meta["size"][1], meta["size"][0], 3) for frame in reader]
    return frames, meta["fps"], tuple(meta["size"])


def test_each_episode_is_recorded_frame_by_frame_and_plays_as_without_video(trained_run, tmp_path):
    policy = ilcsan.load(trained_run)
    plain = evaluate_policy(policy, episodes=2, seed=3)
    recorded = evaluate_policy(policy, episodes=2, seed=3, video=tmp_path / "videos")
    assert recorded == plain  # rendering reads the state, it does not change the episode
    assert sorted(p.name for p in (tmp_path / "videos").iterdir()) == ["Pendulum-v1-seed3.mp4", "Pendulum-v1-seed4.mp4"]
    for seed, length in zip((3, 4), plain[1], strict=True):
        frames, fps, size = read_video(tmp_path / "videos" / f"Pendulum-v1-seed{seed}.mp4")
        assert len(frames) == length + 1  # the reset's frame and one per step
        assert fps == 30 and size == (500, 500)  # Pendulum's own frame rate and size
        assert len({frame.tobytes() for frame in frames[:20]}) > 1  # the pendulum moves


def test_a_mujoco_episode_renders_off_screen_with_a_camera_that_follows_the_body(tmp_path):
    for variable in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "SDL_VIDEODRIVER", "DISPLAY", "WAYLAND_DISPLAY"):
        os.environ.pop(variable, None)  # headless, nothing chosen: EGL must be picked for the user

    def push_forward(observation):
        return np.array([1.0, -1.0, 1.0])  # a saturated action: the hopper falls within a second

    try:
        returns, lengths = run_episodes(push_forward, "Hopper", 1, seed=0, video=tmp_path)
    except UserError as error:  # a machine without EGL's libraries: the failure must be the one line that says so
        assert "render" in str(error) and "MUJOCO_GL=osmesa" in str(error)
        pytest.skip(f"no off-screen OpenGL on this machine ({error})")
    assert returns == run_episodes(push_forward, "Hopper", 1, seed=0)[0]
    frames, fps, size = read_video(tmp_path / "Hopper-seed0.mp4")
    assert len(frames) == lengths[0] + 1 and fps == 125 and size == (480, 480)

    # a hopper 5 m further on is still in the middle of the picture (Gymnasium's default camera would have lost it)
    recorder = EpisodeVideo(make_env("Hopper", render_mode="rgb_array"), tmp_path / "moved", "Hopper")
    recorder.reset(seed=0)
    simulation = recorder.unwrapped
    position, velocity = simulation.data.qpos.copy(), simulation.data.qvel.copy()
    position[0] += 5.0
    simulation.set_state(position, velocity)
    for frame in (frames[0], recorder.render()):
        red, blue = frame[..., 0].astype(int), frame[..., 2].astype(int)
        body = np.argwhere((red > 120) & (red > blue + 60))  # its brown pixels
        assert len(body) > 500 and 200 < body[:, 1].mean() < 280
    recorder.close()


def test_an_episode_that_does_not_end_leaves_no_file(trained_run, tmp_path):
    policy = ilcsan.load(trained_run)
    calls = 0

    def interrupted(observations):
        nonlocal calls
        calls += 1
        if calls == 5:
            raise KeyboardInterrupt
        return policy.predict(observations)

    with pytest.raises(KeyboardInterrupt):
        run_episodes(interrupted, "Pendulum-v1", 2, seed=0, batched=True, video=tmp_path)
    assert list(tmp_path.iterdir()) == []  # neither a video nor a temporary file


# Gymnasium's OffScreenViewer, whose OpenGL context was never made, fails in its __del__ (ignored by Python)
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_machine_that_cannot_render_gets_one_line_that_says_what_to_set(tmp_path):
    import mujoco  # noqa: F401 - imported before, as in any process that has built a MuJoCo task

    os.environ["MUJOCO_GL"] = "no-such-backend"  # as a machine without the OpenGL back-end asked for
    with pytest.raises(UserError, match="render") as raised:
        run_episodes(lambda observation: np.zeros(1), "InvertedPendulum-v5", 1, video=tmp_path)
    assert str(raised.value).endswith(RENDERING_FIX) and "\n" not in str(raised.value)
    assert list(tmp_path.iterdir()) == []
    del raised
    gc.collect()  # that viewer's __del__ runs here, under this test's filter


def test_a_folder_that_cannot_hold_videos_is_one_line(tmp_path):
    (tmp_path / "a-file").write_text("")
    with pytest.raises(UserError, match="cannot write the video .*a-file/videos/Pendulum-v1-seed0.mp4") as raised:
        run_episodes(lambda observation: np.zeros(1), "Pendulum-v1", 1, video=tmp_path / "a-file" / "videos")
    assert "\n" not in str(raised.value)


def test_the_command_names_the_videos_and_says_how_to_get_the_encoder(trained_run, tmp_path, capsys, monkeypatch):
    code, out, _ = run_cli(capsys, "evaluate", str(trained_run), "--episodes", "2", "--seed", "7",
                           "--video", str(tmp_path / "v"))
    assert code == 0
    assert f"video of each episode: {tmp_path / 'v' / 'Pendulum-v1-seed7.mp4'} … Pendulum-v1-seed8.mp4" in out
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # as if the video extra were not installed
    code, out, err = run_cli(capsys, "evaluate", str(trained_run), "--video", str(tmp_path / "w"))
    assert_one_line_error(code, err, "imageio-ffmpeg", "pip install 'ilcsan[video]'")
    assert out == "" and not (tmp_path / "w").exists()


def test_a_long_evaluation_shows_its_progress_over_the_episodes_steps(trained_run, capsys):
    policy = ilcsan.load(trained_run)
    returns = evaluate_policy(policy, episodes=2, seed=3, progress=True)
    err = capsys.readouterr().err
    counts = [int(count) for count in re.findall(r"Pendulum-v1: 2 episodes:.*?(\d+)/400 ", err)]
    assert counts[0] == 0 and max(counts) > 0  # over 2 episodes × Pendulum's 200-step limit, counting
    assert returns == evaluate_policy(policy, episodes=2, seed=3)
    assert capsys.readouterr().err == ""  # off unless asked for (the command asks when stderr is a terminal)
