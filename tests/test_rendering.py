"""Offscreen frames and the episode recorder (skipped, with the reason, where no GL is available)."""

import numpy as np
import pytest
from frame_strip import main as frame_strip_main
from frame_strip import strip_indices
from helpers import hold_pose
from PIL import Image

from roto_trl import TASKS, make_env
from roto_trl.envs.rendering import LIT_RGBA
from roto_trl.record import main as record_main
from roto_trl.utils.video import read_mp4


def render_or_skip(env, **kwargs):
    try:
        return env.render(0, **kwargs)
    except RuntimeError as err:
        if "no OpenGL context" in str(err):
            pytest.skip(f"no offscreen OpenGL on this machine: {err}")
        raise


@pytest.mark.parametrize("task", sorted(TASKS))
def test_render_gives_a_non_blank_frame_with_lit_sensors(task):
    env = make_env(task, 2, seed=0)
    hold_pose(env, 20)
    base = env.base_env
    frame = render_or_skip(env, width=320, height=240)
    assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8
    assert frame.std() > 20  # a scene, not a flat colour
    lit = np.all(np.abs(frame.astype(int) - (LIT_RGBA[:3] * 255).astype(int)) < 60, axis=-1)
    active = bool((base._robot_obs(base._reading())["contact_force"][0] > 0).any())
    plain = base.render(0, width=320, height=240, show_contacts=False)
    # sensors in contact are drawn lit; without contacts (or with them hidden) nothing is
    assert bool(lit.any() or not active)
    assert (not active) or not np.array_equal(frame, plain)
    env.close()


def test_baoding_is_seen_from_above_too():
    env = make_env("baoding", 1, seed=0)
    hold_pose(env, 5)
    above = render_or_skip(env, camera="roto:above", width=160, height=120)
    assert above.std() > 20 and not np.array_equal(above, env.render(0, width=160, height=120))
    env.close()


def test_render_rejects_a_bad_index_and_camera():
    env = make_env("bounce", 1)
    env.reset()
    with pytest.raises(IndexError, match="env_index 3 out of range"):
        env.render(3)
    with pytest.raises(ValueError, match="no camera 'top'"):
        env.render(0, camera="top")
    env.close()


def test_record_writes_an_mp4_of_the_episode(tmp_path):
    out = tmp_path / "find.mp4"
    env = make_env("find", 1)
    env.reset()
    render_or_skip(env, width=64, height=48)
    env.close()
    record_main(["task=find", f"out={out}", "max_steps=12", "width=160", "height=120"])
    frames = read_mp4(out)
    assert len(frames) == 13  # the first observation, then one frame per step
    assert frames[0].shape == (120, 160, 3) and frames[-1].std() > 10
    strip = tmp_path / "strip.png"  # the docs' frame strip of that video: 0 to 0.2 s at 60 frames a second
    assert frame_strip_main([str(out), "--frames", "3", "--out", str(strip)]) == 0
    width, height = Image.open(strip).size
    assert width > 2 * height  # three frames side by side
    with pytest.raises(SystemExit, match=r"--start 1 s must lie in the video's 0-0\.20 s, the start first"):
        frame_strip_main([str(out), "--start", "1", "--out", str(strip)])


def test_frame_strip_takes_frames_evenly_from_the_window():
    assert strip_indices(601, 5, 0.0, None) == [0, 150, 300, 450, 600]  # a whole 10 s episode
    assert strip_indices(601, 3, 1.0, 2.0) == [60, 90, 120]  # from 1 s to 2 s
    with pytest.raises(ValueError, match="holds 3 frames, fewer than --frames 4"):
        strip_indices(601, 4, 1.0, 1 + 2 / 60)


def test_record_rejects_unknown_keys_and_tasks():
    with pytest.raises(SystemExit, match="unknown key 'polcy'"):
        record_main(["task=find", "polcy=random"])
    with pytest.raises(SystemExit, match="give task="):
        record_main(["task=juggle"])
