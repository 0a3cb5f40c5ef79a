"""Smoke tests of every learner: a few hundred steps, finite losses, checkpoints that load and act the same,
clear errors for corrupt or mismatched checkpoints, resume."""

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("rsl_rl")

from mjdrive.agents.algorithms import agent_class  # noqa: E402
from mjdrive.agents.checkpoints import CheckpointError, load_checkpoint, save_checkpoint  # noqa: E402
from mjdrive.agents.config import apply_overrides, load_config  # noqa: E402
from mjdrive.agents.evaluate import evaluate, load_agent, to_markdown  # noqa: E402
from mjdrive.agents.train import train  # noqa: E402
from mjdrive.envs.batched import BatchedEnv  # noqa: E402

SMALL = ["num_envs=2", "nthread=1", "checkpoint_every=128", "log_every=50", "tensorboard=false",
         "torch_threads=1"]
OFF_POLICY = ["algorithm.learning_starts=64", "algorithm.batch_size=16", "algorithm.updates_per_step=0.5"]
CAMERA = ["task_kwargs.observation=camera", "task_kwargs.image_size=32"]
SMALL_CNN = "{channels: [8, 8, 16], kernel: 5, stride: 2, pool: avg}"
PPO_CNN = "{output_channels: [8, 16], kernel_size: [5, 3], stride: [2, 2], activation: relu, flatten: true}"

CASES = {
    "ppo_mlp": ("ppo", ["steps=256", "rsl_rl.num_steps_per_env=32"]),
    "ppo_cnn": ("ppo_camera", ["steps=128", "rsl_rl.num_steps_per_env=32", *CAMERA,
                               f"rsl_rl.actor.cnn_cfg={PPO_CNN}", f"rsl_rl.critic.cnn_cfg={PPO_CNN}"]),
    "sac_mlp": ("sac", ["steps=256", *OFF_POLICY]),
    "sac_cnn": ("sac", ["steps=160", *OFF_POLICY, *CAMERA, f"algorithm.cnn={SMALL_CNN}"]),
    "dqn_mlp": ("dqn", ["steps=256", *OFF_POLICY, "algorithm.target_every=10"]),
    "dqn_cnn": ("dqn_camera", ["steps=160", "task=waypoints/straight", *OFF_POLICY, *CAMERA,
                               f"algorithm.cnn={SMALL_CNN}"]),
    "trpo_mlp": ("trpo", ["steps=256", "algorithm.rollout_steps=32"]),
    # study 002's decisions with its network (the group extractor of Fig. 6)
    "trpo_decisions": ("trpo_crossroad", ["steps=128", "algorithm.rollout_steps=16"]),
    "ppo_discrete_decisions": ("ppo_discrete", ["steps=128", "algorithm.rollout_steps=16"]),
}


def _config(name: str, overrides: list[str]) -> dict:
    return apply_overrides(load_config(name), SMALL + overrides)


def _observations(config: dict, n: int = 3) -> dict:
    task_kwargs = config.get("task_kwargs", {})
    env = BatchedEnv(*config["task"].split("/"), num_envs=n, actions=config["actions"], **task_kwargs)
    obs, _ = env.reset(seed=1)
    for _ in range(5):
        obs = env.step(np.stack([env.single_action_space.sample() for _ in range(n)]))[0]
    env.close()
    return obs


@pytest.mark.parametrize("case", sorted(CASES))
def test_learner_trains_saves_and_reloads(case, tmp_path):
    name, overrides = CASES[case]
    config = _config(name, overrides)
    policy_path = train(config, tmp_path, progress=False)
    scalars = json.loads((tmp_path / "scalars.json").read_text())
    losses = {k: v for k, v in scalars["latest"].items() if "loss" in k}
    assert losses and all(np.isfinite(v) for v in losses.values()), scalars
    assert scalars["env_steps"] >= config["steps"]
    assert (tmp_path / "episodes.csv").exists() and list((tmp_path / "checkpoints").glob("step_*.pt"))
    # the small policy file and the full checkpoint act identically on the same observations
    obs = _observations(config)
    small, payload = load_agent(policy_path)
    full, _ = load_agent(tmp_path / "checkpoint.pt")
    assert payload["extra"]["inference_only"] and payload["config"]["algo"] == config["algo"]
    np.testing.assert_array_equal(small.act(obs), full.act(obs))
    assert policy_path.stat().st_size < 5e6


def test_the_group_extractor_reads_each_group_through_its_own_network():
    """Study 002's Fig. 6: the ego's features and the adversary matrix pass separate MLPs; an adversary change
    moves only the adversary half of the encoding, an ego change only the ego half."""
    import gymnasium as gym

    from mjdrive.agents.networks import GroupEncoder
    from mjdrive.envs.batched import ObservationLayout

    space = gym.spaces.Dict({"adversaries": gym.spaces.Box(0, 1, (6, 4)), "ego": gym.spaces.Box(0, 1, (4,)),
                             "scenario": gym.spaces.Box(0, 1, (5,))})
    layout = ObservationLayout(space)
    torch.manual_seed(0)
    encoder = GroupEncoder(layout, {"ego": ["ego", "scenario"], "adversaries": ["adversaries"]}, [16, 8])
    assert encoder.out_dim == 16
    obs = {key: np.random.default_rng(1).random((2, *sub.shape)).astype(np.float32) for key, sub in space.items()}
    base = encoder(torch.as_tensor(layout.features(obs)))
    moved = {**obs, "adversaries": obs["adversaries"] + 0.5}
    out = encoder(torch.as_tensor(layout.features(moved)))
    assert torch.equal(out[:, :8], base[:, :8]) and not torch.allclose(out[:, 8:], base[:, 8:])
    moved = {**obs, "scenario": obs["scenario"][:, ::-1].copy()}
    out = encoder(torch.as_tensor(layout.features(moved)))
    assert not torch.allclose(out[:, :8], base[:, :8]) and torch.equal(out[:, 8:], base[:, 8:])
    with pytest.raises(ValueError, match="each observation key once"):
        GroupEncoder(layout, {"ego": ["ego"], "adversaries": ["adversaries"]}, [8])  # scenario unread
    with pytest.raises(ValueError, match="unknown: \\['speed'\\]"):
        GroupEncoder(layout, {"ego": ["ego", "scenario", "speed"], "adversaries": ["adversaries"]}, [8])


@pytest.mark.parametrize("algo", ["sac", "dqn", "trpo"])
def test_in_memory_agent_and_reloaded_agent_act_the_same(algo, tmp_path):
    config = _config(algo, ["algorithm.hidden=[32, 32]"])
    env = BatchedEnv("waypoints", "straight", num_envs=3, actions=config["actions"])
    agent = agent_class(algo)(config, env.single_observation_space, env.single_action_space)
    for p in (agent.q if algo == "dqn" else agent.policy if algo == "trpo" else agent.actor).parameters():
        torch.nn.init.normal_(p, std=0.3)  # not the initial weights
    save_checkpoint(tmp_path / "agent.pt", algo, config, agent.state_dict(), step=0)
    reloaded, _ = load_agent(tmp_path / "agent.pt")
    obs, _ = env.reset(seed=0)
    np.testing.assert_array_equal(agent.act(obs), reloaded.act(obs))
    env.close()


def test_corrupt_wrong_and_mismatched_checkpoints_raise_clear_errors(tmp_path):
    config = _config("sac", ["algorithm.hidden=[32, 32]"])
    env = BatchedEnv("waypoints", "straight", num_envs=1)
    agent = agent_class("sac")(config, env.single_observation_space, env.single_action_space)
    env.close()
    path = save_checkpoint(tmp_path / "sac.pt", "sac", config, agent.state_dict(), step=10)
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(CheckpointError, match="corrupt"):
        load_checkpoint(truncated)
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "missing.pt")
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, other)
    with pytest.raises(CheckpointError, match="not an mjdrive agent checkpoint"):
        load_checkpoint(other)
    with pytest.raises(CheckpointError, match="holds a 'sac' agent, expected 'dqn'"):
        load_checkpoint(path, algo="dqn")
    payload = torch.load(path, weights_only=True)
    payload["config"]["algorithm"]["hidden"] = [64, 64]  # the config no longer matches the weights
    torch.save(payload, tmp_path / "mismatch.pt")
    with pytest.raises(CheckpointError, match="shape mismatches"):
        load_agent(tmp_path / "mismatch.pt")


def test_resume_continues_from_the_checkpoint(tmp_path):
    config = _config("dqn", ["steps=128", *OFF_POLICY, "algorithm.resume_refill=32", "tensorboard=true"])
    train(config, tmp_path, progress=False)
    assert list((tmp_path / "tb").glob("events.out.tfevents.*"))
    first = load_checkpoint(tmp_path / "checkpoint.pt")
    train({**config, "steps": 256}, tmp_path, resume=True, progress=False)
    second = load_checkpoint(tmp_path / "checkpoint.pt")
    assert first["step"] == 128 and second["step"] == 256
    assert second["state"]["updates"] > first["state"]["updates"]
    with pytest.raises(CheckpointError, match="config 'task' differs"):
        train({**config, "steps": 512, "task": "waypoints/four_routes"}, tmp_path, resume=True, progress=False)


def test_resume_may_lower_the_learning_rate_but_not_change_the_network(tmp_path):
    """Fine-tuning: a resumed run takes the config's learning rates; structural settings must still match."""
    config = _config("dqn", ["steps=128", *OFF_POLICY, "algorithm.resume_refill=32"])
    train(config, tmp_path, progress=False)
    assert load_checkpoint(tmp_path / "checkpoint.pt")["state"]["optimizer"]["param_groups"][0]["lr"] == 1e-3
    lower = apply_overrides(config, ["steps=256", "algorithm.lr=1e-4"])
    train(lower, tmp_path, resume=True, progress=False)
    resumed = load_checkpoint(tmp_path / "checkpoint.pt")
    assert resumed["step"] == 256
    assert resumed["state"]["optimizer"]["param_groups"][0]["lr"] == pytest.approx(1e-4)
    assert resumed["config"]["algorithm"]["lr"] == pytest.approx(1e-4)
    wider = apply_overrides(lower, ["steps=384", "algorithm.hidden=[32,32]"])
    with pytest.raises(CheckpointError, match="config 'algorithm' differs.*may change only lr, resume_refill"):
        train(wider, tmp_path, resume=True, progress=False)


def test_resumed_off_policy_run_refills_its_buffer_before_updating(tmp_path):
    """Periodic checkpoints do not keep the replay buffer: a run resumed from one must not take gradient steps
    on a handful of fresh transitions (that overfits the critics); it waits for `resume_refill` of them."""
    config = _config("sac", ["steps=128", *OFF_POLICY, "algorithm.resume_refill=96"])
    train(config, tmp_path, progress=False)
    updates = load_checkpoint(tmp_path / "checkpoint.pt")["state"]["updates"]
    assert updates > 0  # a fresh run updates once learning_starts is reached
    train({**config, "steps": 192}, tmp_path, resume=True, progress=False)  # 64 new transitions < 96
    assert load_checkpoint(tmp_path / "checkpoint.pt")["state"]["updates"] == updates
    train({**config, "steps": 320}, tmp_path, resume=True, progress=False)  # 128 new ones: 32 past the refill
    resumed = load_checkpoint(tmp_path / "checkpoint.pt")["state"]["updates"]
    assert resumed - updates == pytest.approx(0.5 * 32, abs=2)  # updates_per_step x transitions past it


def test_replay_buffer_saves_and_loads_its_transitions_including_after_wrapping(tmp_path):
    from mjdrive.agents.replay import ReplayBuffer
    from mjdrive.envs.batched import ObservationLayout

    config = _config("sac", CAMERA)
    env = BatchedEnv(*config["task"].split("/"), num_envs=3, actions=config["actions"], **config["task_kwargs"])
    obs, _ = env.reset(seed=1)
    layout = ObservationLayout(env.single_observation_space)
    env.close()
    buffer = ReplayBuffer(7, layout, (3,))
    rng = np.random.default_rng(0)
    for _ in range(3):  # 9 transitions into 7 slots: wraps, position 2
        varied = {k: (v + rng.integers(0, 50, v.shape)).astype(v.dtype) for k, v in obs.items()}
        buffer.add(varied, rng.normal(size=(3, 3)).astype(np.float32), rng.normal(size=3), obs,
                   rng.integers(0, 2, 3))
    assert buffer.size == 7 and buffer.position == 2
    buffer.save(tmp_path / "replay", step=9)
    restored = ReplayBuffer(7, layout, (3,))
    restored.load(tmp_path / "replay", step=9)
    oldest_first = np.r_[2:7, 0:2]  # restored in the order they were added; the next add overwrites the oldest
    assert (restored.size, restored.position) == (7, 0)
    for name in ReplayBuffer.ARRAYS:
        np.testing.assert_array_equal(getattr(restored, name), getattr(buffer, name)[oldest_first])
    with pytest.raises(ValueError, match="saved at env step 9, the checkpoint is at 12"):
        ReplayBuffer(7, layout, (3,)).load(tmp_path / "replay", step=12)
    smaller = ReplayBuffer(4, layout, (3,))  # a resumed run with a smaller buffer keeps the newest transitions
    smaller.load(tmp_path / "replay", step=9)
    assert (smaller.size, smaller.position) == (4, 0)
    np.testing.assert_array_equal(smaller.actions, buffer.actions[oldest_first[-4:]])
    np.testing.assert_array_equal(smaller.images, buffer.images[oldest_first[-4:]])
    larger = ReplayBuffer(10, layout, (3,))  # a larger one gets all of them, oldest first, and fills on
    larger.load(tmp_path / "replay", step=9)
    assert (larger.size, larger.position) == (7, 7)
    np.testing.assert_array_equal(larger.rewards[:7], buffer.rewards[oldest_first])
    with pytest.raises(ValueError, match="actions is float32\\[7, 3\\], this run stores float32\\[7, 2\\]"):
        ReplayBuffer(7, layout, (2,)).load(tmp_path / "replay", step=9)


def test_interrupted_off_policy_run_saves_its_buffer_and_resumes_without_the_refill(tmp_path, monkeypatch):
    """Ctrl-C mid-run: checkpoint.pt and replay/ at the same step; --resume restores the transitions and
    updates at once instead of waiting for `resume_refill` new ones (contrast with the test above)."""
    config = _config("sac", ["steps=400", *OFF_POLICY, "algorithm.resume_refill=96"])
    step = BatchedEnv.step
    calls = []

    def interrupted_step(self, actions):
        calls.append(1)
        if len(calls) == 60:  # 59 steps of 2 copies done
            raise KeyboardInterrupt
        return step(self, actions)

    monkeypatch.setattr(BatchedEnv, "step", interrupted_step)
    with pytest.raises(KeyboardInterrupt):
        train(config, tmp_path, progress=False)
    monkeypatch.setattr(BatchedEnv, "step", step)
    saved = load_checkpoint(tmp_path / "checkpoint.pt")
    assert saved["step"] == 118
    assert json.loads((tmp_path / "replay" / "meta.json").read_text())["size"] == 118
    updates = saved["state"]["updates"]
    assert updates > 0
    train({**config, "steps": 182}, tmp_path, resume=True, progress=False)  # 64 new transitions < the refill
    resumed = load_checkpoint(tmp_path / "checkpoint.pt")["state"]["updates"]
    assert resumed - updates == pytest.approx(0.5 * 64, abs=2)  # every new transition counted at once


def test_sigterm_stops_mjdrive_train_with_its_state_saved(tmp_path):
    """`kill` (SIGTERM) stops `mjdrive train` like Ctrl-C: exit code 130, checkpoint.pt and replay/ written."""
    import signal
    import subprocess
    import sys
    import time

    overrides = [f"--set={pair}" for pair in SMALL + OFF_POLICY] + ["--set=checkpoint_every=32"]
    process = subprocess.Popen([sys.executable, "-m", "mjdrive.cli", "train", "--algo", "sac", "--steps", "100000",
                                "--out", str(tmp_path), "--no-progress", *overrides],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 120
    while not (tmp_path / "checkpoints" / "step_32.pt").exists():
        assert process.poll() is None, process.communicate()[0]
        assert time.monotonic() < deadline, "no checkpoint within 120 s"
        time.sleep(0.2)
    process.send_signal(signal.SIGTERM)
    output = process.communicate(timeout=60)[0]
    assert process.returncode == 130, output
    step = load_checkpoint(tmp_path / "checkpoint.pt")["step"]
    assert step >= 32 and "continue with --resume" in output
    assert json.loads((tmp_path / "replay" / "meta.json").read_text())["step"] == step


def test_a_new_run_can_start_from_another_runs_networks_on_another_camera(tmp_path):
    """`init_from`: a camera agent fine-tuned onto the wide camera keeps its networks and updates counter,
    refills its empty buffer with the loaded policy first, and refuses other learners or network shapes."""
    source = _config("sac", ["steps=128", "task=roundabout/d120", "actions=pedal", *OFF_POLICY, *CAMERA,
                             "task_kwargs.camera_ego=true", f"algorithm.cnn={SMALL_CNN}"])
    train(source, tmp_path / "source", progress=False)
    saved = load_checkpoint(tmp_path / "source" / "checkpoint.pt")
    assert saved["state"]["updates"] > 0
    wide = apply_overrides(source, ["steps=128", "checkpoint_every=32", "task_kwargs.camera=front_wide",
                                    "algorithm.actor_lr=1e-4", "algorithm.resume_refill=96",
                                    f"init_from={tmp_path / 'source' / 'checkpoint.pt'}"])
    train(wide, tmp_path / "wide", progress=False)
    started = load_checkpoint(tmp_path / "wide" / "checkpoints" / "step_64.pt")  # 64 transitions < 96
    assert started["state"]["updates"] == saved["state"]["updates"]  # no update yet
    for name, value in saved["state"]["actor"].items():
        torch.testing.assert_close(started["state"]["actor"][name], value)
    assert started["state"]["actor_optimizer"]["param_groups"][0]["lr"] == pytest.approx(1e-4)
    final = load_checkpoint(tmp_path / "wide" / "checkpoint.pt")
    assert final["step"] == 128 and final["extra"]["experience"] == saved["step"]  # its own steps + the source's
    assert final["state"]["updates"] - saved["state"]["updates"] == pytest.approx(0.5 * 32, abs=2)
    with pytest.raises(CheckpointError, match="holds only the acting network.*critic_warmup"):
        train({**wide, "init_from": str(tmp_path / "source" / "policy.pt")}, tmp_path / "x", progress=False)
    wider = apply_overrides(wide, ["algorithm.hidden=[32,32]"])
    with pytest.raises(CheckpointError, match="cannot start from .*config 'algorithm' differs"):
        train(wider, tmp_path / "y", progress=False)
    with pytest.raises(CheckpointError, match="cannot start from .*config 'algorithm' differs"):
        train({**wider, "algorithm": {**wider["algorithm"], "critic_warmup": 8},
               "init_from": str(tmp_path / "source" / "policy.pt")}, tmp_path / "y2", progress=False)

    # from a policy.pt (actor and encoder only): new critics learn alone for `critic_warmup` updates
    acting = apply_overrides(wide, ["checkpoint_every=16", "algorithm.critic_warmup=10", "algorithm.alpha=0.05",
                                    f"init_from={tmp_path / 'source' / 'policy.pt'}"])
    train(acting, tmp_path / "acting", progress=False)
    before = load_checkpoint(tmp_path / "acting" / "checkpoints" / "step_80.pt")["state"]
    warm = load_checkpoint(tmp_path / "acting" / "checkpoints" / "step_112.pt")["state"]
    final = load_checkpoint(tmp_path / "acting" / "checkpoint.pt")["state"]
    assert before["updates"] == 0 and 0 < warm["updates"] <= 10 < final["updates"]
    for name, value in saved["state"]["actor"].items():
        torch.testing.assert_close(warm["actor"][name], value)  # the actor and the encoder wait
        if name.startswith("encoder."):  # the target critic starts from the loaded encoder
            torch.testing.assert_close(before["critic_target"][name], value)
    assert not torch.equal(warm["critic"]["q1.0.weight"], before["critic"]["q1.0.weight"])
    for name in ("mean.weight", "encoder.cnn.net.0.weight"):  # then the actor and the encoder learn
        assert not torch.equal(final["actor"][name], saved["state"]["actor"][name])

    # freeze_encoder (a fine-tuning setting, so it may differ from the source's): only the heads learn
    frozen = apply_overrides(acting, ["algorithm.freeze_encoder=true",
                                      f"init_from={tmp_path / 'acting' / 'checkpoint.pt'}"])
    train(frozen, tmp_path / "frozen", progress=False)
    after = load_checkpoint(tmp_path / "frozen" / "checkpoint.pt")["state"]
    assert after["updates"] > final["updates"]
    for name, value in final["critic"].items():
        same = torch.equal(after["critic"][name], value)
        assert same == name.startswith("encoder."), name
    assert not torch.equal(after["actor"]["mean.weight"], final["actor"]["mean.weight"])
    with pytest.raises(CheckpointError, match="only sac, dqn runs can start"):
        train({**_config("ppo", ["steps=64"]), "init_from": str(tmp_path / "source" / "checkpoint.pt")},
              tmp_path / "z", progress=False)


def test_evaluate_reports_route_completion(tmp_path):
    config = _config("sac", ["steps=64", "algorithm.learning_starts=1000"])
    policy = train(config, tmp_path, progress=False)
    result = evaluate(policy, episodes=2, task_kwargs={"time_limit": 2.0})
    assert len(result["rows"]) == 2 and 0.0 <= result["summary"]["route_completion_mean"] <= 1.0
    assert result["rows"][0]["end"] in ("time_limit", "lane_invasion", "off_road", "collision", "arrived")
    markdown = to_markdown(result)
    assert "route completion mean" in markdown and markdown.count("\n| ") >= 4
    sampled = [evaluate(policy, episodes=2, task_kwargs={"time_limit": 2.0}, deterministic=False)["rows"]
               for _ in range(2)]
    assert sampled[0] == sampled[1]  # sampled actions are seeded per episode
    assert [r["reward"] for r in sampled[0]] != [r["reward"] for r in result["rows"]]


def test_rsl_rl_vecenv_groups_actions_and_time_outs():
    from mjdrive.envs.rsl_rl_env import RslRlVecEnv

    batched = BatchedEnv("waypoints", "straight", num_envs=2, observation="camera", image_size=32, time_limit=0.5)
    env = RslRlVecEnv(batched, reward_scale=0.5)
    obs = env.get_observations()
    assert obs.batch_size == torch.Size([2]) and obs["policy"].shape == (2, 3)
    assert obs["image"].shape == (2, 3, 32, 32) and 0.0 <= obs["image"].min() and obs["image"].max() <= 1.0
    assert env.num_actions == 3 and env.max_episode_length == 5
    np.testing.assert_allclose(env.env_actions(torch.tensor([[-1.0, 0.0, -1.0], [1.0, 2.0, 0.0]])),
                               [[0.0, 0.0, 0.0], [1.0, 1.0, 0.5]])  # clipped, mapped onto the bounds
    for step in range(5):
        obs, rewards, dones, extras = env.step(torch.zeros(2, 3))
        assert rewards.dtype == torch.float32 and rewards.shape == (2,)
        assert bool(dones.any()) == (step == 4) and torch.equal(extras["time_outs"], dones.bool())
    assert "/episode/route_completion" in extras["log"] and len(env.completed) == 2
    assert env.episode_length_buf.tolist() == [0, 0]
    env.close()
    with pytest.raises(ValueError, match="continuous actions"):
        RslRlVecEnv(BatchedEnv("waypoints", "straight", num_envs=1, actions="table1"))


def test_random_shift_moves_each_frame_stack_by_its_own_offset_with_edge_padding():
    from mjdrive.agents.augment import random_shift

    image = torch.arange(2 * 3 * 20 * 20, dtype=torch.int64).reshape(2, 3, 20, 20).to(torch.float32)
    shifted = random_shift(image, 4, generator=torch.Generator().manual_seed(0))
    assert shifted.shape == image.shape and torch.equal(random_shift(image, 0), image)
    for b in range(2):
        # find the offset from the centre pixel, then check the whole stack against pad-with-edge + crop
        centre = shifted[b, 0, 10, 10].item()
        dy, dx = divmod(int(centre) - 400 * 3 * b, 20)
        dy, dx = dy - 10, dx - 10
        assert -4 <= dy <= 4 and -4 <= dx <= 4
        rows = (torch.arange(20) + dy).clamp(0, 19)
        cols = (torch.arange(20) + dx).clamp(0, 19)
        assert torch.equal(shifted[b], image[b][:, rows][:, :, cols])
    many = random_shift(image.repeat(16, 1, 1, 1), 4, generator=torch.Generator().manual_seed(1))
    assert len({tuple(many[i, 0, 10, 10:12].tolist()) for i in range(32)}) > 5  # offsets differ per sample


def test_sac_actor_reads_the_critics_encoder_and_only_the_critic_trains_it():
    config = _config("sac", [*CAMERA, f"algorithm.cnn={SMALL_CNN}", "algorithm.policy_every=1"])
    env = BatchedEnv("waypoints", "straight", num_envs=2, observation="camera", image_size=32)
    agent = agent_class("sac")(config, env.single_observation_space, env.single_action_space)
    env.close()
    assert agent.actor.encoder is agent.critic.encoder
    encoder_ids = {id(p) for p in agent.critic.encoder.parameters()}
    actor_ids = {id(p) for group in agent.actor_optimizer.param_groups for p in group["params"]}
    assert encoder_ids and not encoder_ids & actor_ids  # the actor's optimizer never steps the encoder
    from mjdrive.agents.observations import ObsBatch

    def batch():
        return ObsBatch(torch.randn(8, 3), torch.randint(0, 256, (8, 3, 32, 32), dtype=torch.uint8))

    data = {"obs": batch(), "next_obs": batch(), "actions": torch.rand(8, 3) * 2 - 1,
            "rewards": torch.randn(8), "terminated": torch.zeros(8)}
    before = [p.detach().clone() for p in agent.critic.encoder.parameters()]
    info = agent.update(data)
    assert np.isfinite(info["critic_loss"]) and np.isfinite(info["actor_loss"])
    assert any(not torch.equal(a, b) for a, b in zip(before, agent.critic.encoder.parameters(), strict=True))


def test_sac_greedy_action_is_the_squashed_mean_of_the_sampling_path_bit_for_bit():
    """`act(deterministic=True)` skips the draw and its log-probability; its actions must stay those of
    `sample`'s third output (the published evaluation tables were made with it)."""
    from mjdrive.agents.observations import ObsBatch

    config = _config("sac", [])
    env = BatchedEnv("waypoints", "straight", num_envs=2)
    agent = agent_class("sac")(config, env.single_observation_space, env.single_action_space)
    obs, _ = env.reset(seed=3)
    env.close()
    with torch.no_grad():
        for p in agent.actor.parameters():  # away from the initial weights, so the heads' outputs spread
            p.add_(0.02 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel())))
        latent = torch.randn(64, agent.actor.encoder.out_dim, generator=torch.Generator().manual_seed(1))
        greedy = agent.actor.greedy(latent)
        sampled, _, mean = agent.actor.sample(latent)
        want = agent.actor.to_env(agent.actor.sample(agent.actor.encode(
            ObsBatch.from_numpy(agent.layout, obs)))[2]).numpy()
    assert torch.equal(greedy, mean) and not torch.equal(greedy, sampled)
    assert greedy.abs().max() < 1 and greedy.std() > 0.05
    np.testing.assert_array_equal(agent.act(obs, deterministic=True), want)


def test_sac_bc_alpha_pulls_the_actor_towards_the_demonstrated_actions():
    """TD3+BC's term: with bc_alpha > 0 the greedy action moves to the demonstrations' actions (the batch rows
    flagged `demonstration`; the others are ignored), without it it need not."""
    from mjdrive.agents.observations import ObsBatch

    env = BatchedEnv("waypoints", "straight", num_envs=1)
    states = torch.randn(16, 18)  # 15 waypoint angles, heading error, lane offset, speed
    features = ObsBatch(torch.cat([states, states]), None)  # each state twice: once the agent's, once demonstrated
    target = torch.tensor([0.6, -0.4, 0.2])
    demonstration = torch.arange(32) >= 16
    actions = torch.where(demonstration[:, None], target, -target)  # the agent's own rows do the opposite
    data = {"obs": features, "next_obs": features, "actions": actions, "rewards": torch.zeros(32),
            "terminated": torch.zeros(32), "demonstration": demonstration}
    distance = {}
    for bc_alpha in (0.0, 0.1):
        torch.manual_seed(0)
        config = _config("sac", ["algorithm.policy_every=1", "algorithm.actor_lr=3e-3",
                                 f"algorithm.bc_alpha={bc_alpha}"])
        agent = agent_class("sac")(config, env.single_observation_space, env.single_action_space)
        for _ in range(60):
            info = agent.update(data)
        assert ("bc_loss" in info) == (bc_alpha > 0)
        with torch.no_grad():
            mean_action = agent.actor.sample(agent.actor.encode(features))[2]
        distance[bc_alpha] = float((mean_action[demonstration] - target).abs().max())
    env.close()
    assert distance[0.1] < 0.1 < 0.5 < distance[0.0], distance


def test_episode_log_is_flushed_as_episodes_end_and_resume_drops_later_rows(tmp_path):
    from mjdrive.agents.run_log import Run

    def ended(n):
        return [{"episode_return": float(i), "episode_length": 10, "success": False, "task": "roundabout/d120"}
                for i in range(n)]

    config = {"algo": "sac", "checkpoint_every": 0}
    run = Run(tmp_path, config, total_steps=100, progress=False, tensorboard=False)
    run.add_steps(20, ended(2))
    run.save("sac", {}, periodic=False)  # the checkpoint a resumed run restarts from: episode 2, step 20
    run.add_steps(20, [None, *ended(1)])
    rows = (tmp_path / "episodes.csv").read_text().splitlines()
    assert len(rows) == 1 + 3  # readable before close: a killed run keeps them
    run._csv_file.close()  # killed: Run.close never ran; the OS closed the file (flushed rows only)
    del run
    resumed = Run(tmp_path, config, total_steps=100, start_step=20, start_episode=2, progress=False,
                  tensorboard=False)
    resumed.add_steps(20, ended(1))
    resumed.close()
    rows = (tmp_path / "episodes.csv").read_text().splitlines()
    assert [r.split(",")[:2] for r in rows[1:]] == [["1", "20"], ["2", "20"], ["3", "40"]]
    assert rows[0].endswith(",time_limit,task") and all(r.endswith(",roundabout/d120") for r in rows[1:])
    walls = [float(r.split(",")[2]) for r in rows[1:]]
    assert walls == sorted(walls)  # wall-clock counts on from the resumed checkpoint


def test_select_checkpoint_ranks_a_runs_checkpoints_and_exports_the_chosen_one(tmp_path):
    from tools import select_checkpoint as tool

    assert sorted([tool.rank_key({"success_pct": 90, "collision_pct": 10, "avg_reward": 5}),
                   tool.rank_key({"success_pct": 95, "collision_pct": 5, "avg_reward": 1}),
                   tool.rank_key({"success_pct": 90, "collision_pct": 5, "avg_reward": 1})])[0] == (-95, 5, -1)

    run = tmp_path / "run"
    train(_config("sac", ["steps=256", *OFF_POLICY, "checkpoint_every=128"]), run, progress=False)
    assert [step for step, _ in tool.run_checkpoints(run)] == [128, 256]
    assert [step for step, _ in tool.run_checkpoints(run, first=200)] == [256]
    with pytest.raises(FileNotFoundError, match="no checkpoints"):
        tool.run_checkpoints(run, first=1000)
    out = tmp_path / "selection"
    tool.main([str(run), "--episodes", "1", "--export", str(tmp_path / "chosen.pt"), "--out", str(out)])
    report = json.loads(out.with_suffix(".json").read_text())
    assert [r["step"] for r in report["checkpoints"]] == [128, 256]
    best = min(report["checkpoints"], key=lambda r: tool.rank_key(r["summary"]))
    assert report["chosen"] == best["step"]
    exported = load_checkpoint(tmp_path / "chosen.pt")
    assert exported["step"] == best["step"] and exported["extra"]["inference_only"]
    assert "**(chosen)**" in out.with_suffix(".md").read_text()
    tool.main([str(run), "--steps", "256", "--episodes", "1", "--out", str(out)])
    assert [r["step"] for r in json.loads(out.with_suffix(".json").read_text())["checkpoints"]] == [256]
    tool.main([str(run), "--steps", "256", "--episodes", "1", "--out", str(out),
               "--task", "waypoints/straight", "waypoints/four_routes"])  # pooled over two tasks
    (row,) = json.loads(out.with_suffix(".json").read_text())["checkpoints"]
    assert list(row["per_task"]) == ["waypoints/straight", "waypoints/four_routes"]
    rewards = [v["avg_reward"] for v in row["per_task"].values()]
    assert rewards[0] != rewards[1] and row["summary"]["avg_reward"] == pytest.approx(sum(rewards) / 2)
    for task, summary in row["per_task"].items():  # the failed episodes' seeds, kept for replaying them
        assert len(row["failures"][task]) == round(100 - summary["success_pct"]) // 100
    tool.main([str(run), "--steps", "256", "--episodes", "1", "--out", str(out), "--time-limit", "1"])
    (row,) = json.loads(out.with_suffix(".json").read_text())["checkpoints"]
    assert row["summary"]["avg_time_s"] == pytest.approx(1.0) and row["summary"]["success_pct"] == 0
    assert "time limit 1 s" in out.with_suffix(".md").read_text()
    with pytest.raises(SystemExit):
        tool.main([str(run), "--steps", "300", "--episodes", "1"])


def test_sac_with_demonstrations_collects_them_and_mixes_them_into_updates(tmp_path, monkeypatch):
    """RLPD-style demonstrations: the scripted driver's transitions are collected first (in the learner's
    action set, rewards scaled), then every update batch holds `fraction` of them."""
    from mjdrive.agents import off_policy

    config = _config("sac", ["steps=128", *OFF_POLICY, "task=roundabout/d120", "actions=pedal",
                             "demonstrations={policy: autopilot, steps: 300, fraction: 0.25}"])
    sizes = []
    concat = off_policy.concat_batches

    def counting_concat(first, second):
        sizes.append((len(first["rewards"]), len(second["rewards"])))
        return concat(first, second)

    monkeypatch.setattr(off_policy, "concat_batches", counting_concat)
    train(config, tmp_path, progress=False)
    summary = json.loads((tmp_path / "demonstrations.json").read_text())
    assert summary["steps"] == 300 and summary["policy"] == "autopilot"
    assert summary["episodes"] >= 1 and summary["success"] == summary["episodes"] and summary["collision"] == 0
    assert sizes and set(sizes) == {(12, 4)}  # batch 16, a quarter from the demonstrations

    from mjdrive.agents.replay import ReplayBuffer
    from mjdrive.envs import make_env
    from mjdrive.envs.batched import ObservationLayout

    env = make_env("roundabout", "d120", actions="pedal", observation="features")
    buffer = ReplayBuffer(300, ObservationLayout(env.observation_space), (2,))
    env.close()
    off_policy.collect_demonstrations(config, buffer, {"policy": "autopilot", "steps": 300}, seed=0,
                                      progress=False)
    assert buffer.size == 300 and np.abs(buffer.actions).max() <= 1.0
    assert buffer.actions[:, 0].max() > 0.1 and buffer.actions[:, 0].min() < -0.1  # it drives and brakes
    assert buffer.terminated.sum() == summary["episodes"]  # every demonstration episode arrived


def test_bad_demonstration_settings_raise_clear_errors(tmp_path):
    base = ["steps=64", *OFF_POLICY, "task=roundabout/d120", "actions=pedal"]
    with pytest.raises(ValueError, match="unknown demonstrations settings"):
        train(_config("sac", [*base, "demonstrations={policy: autopilot, episodes: 3}"]), tmp_path, progress=False)
    with pytest.raises(ValueError, match="fraction"):
        train(_config("sac", [*base, "demonstrations={fraction: 1.0}"]), tmp_path, progress=False)
    with pytest.raises(ValueError, match="unknown policy"):
        train(_config("sac", [*base, "demonstrations={policy: teleport, steps: 10}"]), tmp_path, progress=False)


def test_demonstrations_go_through_the_mixed_tasks_in_turn(monkeypatch):
    """With `mix_tasks`, the scripted driver's episodes cycle over `task` and `mix_tasks` like the copies do."""
    import mjdrive.envs
    from mjdrive.agents import off_policy
    from mjdrive.agents.replay import ReplayBuffer
    from mjdrive.envs.batched import ObservationLayout

    make = mjdrive.envs.make_env
    resets: list[str] = []

    def recording_make_env(domain, name, **kwargs):
        env = make(domain, name, **kwargs)
        reset = env.reset
        env.reset = lambda **kw: (resets.append(name), reset(**kw))[1]
        return env

    monkeypatch.setattr(mjdrive.envs, "make_env", recording_make_env)
    config = _config("sac", ["task=roundabout/d120", "mix_tasks=[roundabout/d160]", "actions=pedal",
                             "task_kwargs={observation: features}"])
    env = make("roundabout", "d120", actions="pedal", observation="features")
    buffer = ReplayBuffer(200, ObservationLayout(env.observation_space), (2,))
    env.close()
    counts = off_policy.collect_demonstrations(config, buffer, {"policy": "autopilot", "steps": 200}, seed=0,
                                               progress=False)
    assert counts["episodes"] >= 2 and counts["success"] == counts["episodes"]
    assert resets[:3] == ["d120", "d160", "d120"][:len(resets)] and len(resets) == counts["episodes"] + 1


def test_roundabout_table3_scores_every_density_with_task_kwargs_over_the_checkpoints(tmp_path):
    """tools/roundabout_table3.py: one row per density; --task-kwarg overrides what the agent trained with
    (here a 1 s time limit, so every episode ends on it) and the report says both."""
    from tools import roundabout_table3 as tool

    run = tmp_path / "run"
    config = _config("sac", ["steps=64", *OFF_POLICY, "task=roundabout/d120", "actions=pedal",
                             "mix_tasks=[roundabout/d140]", "task_kwargs.collision_penalty=300"])
    train(config, run, progress=False)
    out = tmp_path / "table3"
    tool.main(["--agent", "SAC", str(run / "policy.pt"), str(run / "episodes.csv"), "--episodes", "1",
               "--task-kwarg", "time_limit=1", "--task-kwarg", "collision_penalty=100", "--out", str(out)])
    summary = json.loads(out.with_suffix(".json").read_text())["SAC"]
    assert list(summary) == ["d120", "d140", "d160", "d210"]
    for level in summary.values():
        assert level["task_kwargs"]["collision_penalty"] == 100 and level["task_kwargs"]["time_limit"] == 1
        assert level["summary"]["avg_time_s"] <= 1.0 + 1e-9
    report = out.with_suffix(".md").read_text()
    assert "trained on roundabout/d120 + roundabout/d140 {" in report
    assert "'collision_penalty': 300" in report and "scored with {'time_limit': 1, 'collision_penalty': 100}" in report
    # an ensemble reads like a policy and the report names its members
    from mjdrive.agents.ensemble import save_ensemble

    ensemble = save_ensemble([run / "policy.pt", run / "checkpoint.pt"], "min_pedal", tmp_path / "ensemble.pt")
    tool.main(["--agent", "SACx2", str(ensemble), "--episodes", "1", "--levels", "d120", "--task-kwarg",
               "time_limit=1", "--out", str(out)])
    report = out.with_suffix(".md").read_text()
    assert "| SACx2 | d120 |" in report and "an ensemble of 2, rule 'min_pedal', of `" in report
    assert f"`{run / 'checkpoint.pt'}` (sac, 64 steps)" in report


def test_the_cnn_takes_a_kernel_and_stride_per_layer_and_a_downsample():
    """The Nature DQN's layers on a 128 px image averaged to 64 px: 64 -> 15 -> 6 -> 4 pixels, 64 channels."""
    from mjdrive.agents.networks import StudyCNN

    cnn = StudyCNN((3, 128, 128), (32, 64, 64), kernel=[8, 4, 3], stride=[4, 2, 1], pool="none", out_dim=32,
                   downsample=2)
    convs = [m for m in cnn.net if isinstance(m, torch.nn.Conv2d)]
    assert [c.kernel_size for c in convs] == [(8, 8), (4, 4), (3, 3)] and [c.stride for c in convs] == [
        (4, 4), (2, 2), (1, 1)]
    linear = next(m for m in cnn.net if isinstance(m, torch.nn.Linear))
    assert linear.in_features == 64 * 4 * 4 and cnn(torch.zeros(2, 3, 128, 128)).shape == (2, 32)
    image = torch.zeros(1, 3, 128, 128)
    image[..., :2, :2] = 255.0  # one 2x2 block: after averaging, exactly one 64 px pixel changes
    assert torch.equal(cnn.net[0](image / 255.0)[..., 0, 0], torch.ones(1, 3))
    with pytest.raises(ValueError, match="one entry per channel count"):
        StudyCNN((3, 64, 64), (32, 64), kernel=[8, 4, 3])
    with pytest.raises(ValueError, match="downsample"):
        StudyCNN((3, 64, 64), downsample=0)
