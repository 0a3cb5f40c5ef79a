"""Video overlays: the text box, the outcome on the last frame, the legend, and road users recoloured in the
video only (pedestrians no longer share the ego's blue; observations keep their colours)."""

from __future__ import annotations

import numpy as np

from mjdrive.envs import make_env
from mjdrive.video import EGO_RGB, FRONT_SIZE, LEGEND_RGBA, EpisodeVideo, Overlay, video_model


def test_video_recolours_road_users_apart_from_the_ego_and_leaves_the_simulation_alone(tmp_path):
    env = make_env("roundabout", "d120", road_users={"car": 1, "pedestrian": 1})
    env.reset(seed=0)
    model = env.unwrapped.dm_env.physics.model.ptr
    pedestrian = next(i for i in range(model.ngeom) if (model.geom(i).name or "").endswith("_pedestrian"))
    before = model.geom_rgba[pedestrian].copy()
    recoloured = video_model(model)
    assert np.allclose(recoloured.geom_rgba[pedestrian], LEGEND_RGBA["pedestrian"])
    assert np.array_equal(model.geom_rgba[pedestrian], before)  # the observation cameras' model is untouched
    colours = [tuple(np.round(255 * np.array(rgba[:3]))) for rgba in LEGEND_RGBA.values()] + [EGO_RGB]
    assert len(set(colours)) == len(colours)
    distances = [np.linalg.norm(np.subtract(c, EGO_RGB)) for c in colours[:-1]]
    assert min(distances) > 80  # every kind far from the ego's blue
    env.close()


def test_overlay_draws_text_and_legend_and_the_last_frame_holds_the_outcome(tmp_path):
    env = make_env("waypoints", "straight", time_limit=1.0)
    _, info = env.reset(seed=0)
    video = EpisodeVideo(env, tmp_path / "v.mp4")
    bare = video.frame()
    drawn = video.frame(Overlay(step=3, reward=1.5, episode_return=4.5, info=info))
    box = (slice(4, 60), slice(4, 200))
    assert not np.array_equal(bare[box], drawn[box])
    legend = drawn[FRONT_SIZE[0] - 30 :, :400].reshape(-1, 3).astype(int)
    pink = np.round(255 * np.array(LEGEND_RGBA["pedestrian"][:3]))
    assert np.min(np.abs(legend - pink).sum(axis=1)) < 10  # the pedestrian swatch is there
    without_outcome = video.frame(Overlay(step=3, info=info))
    with_outcome = video.frame(Overlay(step=3, info=info, outcome="time_limit"))
    fourth_line = (slice(62, 80), slice(10, 150))
    assert not np.array_equal(without_outcome[fourth_line], with_outcome[fourth_line])  # "outcome: time limit"
    video.add_frame(Overlay(step=0, info=info))
    video.add_frame(Overlay(step=1, info=info, outcome="arrived"))
    video.close()
    import imageio.v2 as imageio

    assert imageio.get_reader(tmp_path / "v.mp4").count_frames() == 1 + video.fps  # the outcome held 1 s
    env.close()


def test_replay_video_has_a_frame_per_step_and_holds_the_outcome(tmp_path):
    import imageio.v2 as imageio

    from mjdrive.envs.replay import replay
    from mjdrive.record import RecordEpisodes

    env = RecordEpisodes(make_env("waypoints", "straight", time_limit=1.0), tmp_path)
    env.reset(seed=2)
    steps, done = 0, False
    while not done:
        *_, terminated, truncated, _ = env.step(np.array([0.5, 0.0, 0.0]))
        steps, done = steps + 1, terminated or truncated
    env.close()
    result = replay(env.recorder.paths[-1], video=tmp_path / "replay.mp4")
    assert result.match
    fps = round(1.0 / env.unwrapped.dm_env.control_timestep())
    assert imageio.get_reader(tmp_path / "replay.mp4").count_frames() == steps + fps  # + the outcome, held 1 s
