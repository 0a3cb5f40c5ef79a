"""PPO through rsl-rl's OnPolicyRunner (MLPModel, or CNNModel for image observations) on RslRlVecEnv.

The config's `rsl_rl` section is rsl-rl's own runner dict (num_steps_per_env, obs_groups, actor, critic,
algorithm); this module only adds mjdrive's bookkeeping around `runner.learn` (progress bar, TensorBoard,
episode log, checkpoints in our format, resume). Study 000 Table 2: actor lr 3e-4 (rsl-rl uses one lr for
both networks), clip 0.1, 4 epochs.
"""

from __future__ import annotations

import contextlib
import copy
import io
import math
import warnings
from collections.abc import Iterator

import gymnasium as gym
import numpy as np
import torch
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils import resolve_class, resolve_obs_groups
from tensordict import TensorDict

from mjdrive.agents.checkpoints import CheckpointError, load_module_state
from mjdrive.agents.env_factory import make_training_env
from mjdrive.agents.run_log import Run
from mjdrive.envs.batched import ObservationLayout
from mjdrive.envs.rsl_rl_env import RslRlVecEnv, action_scaler, to_tensordict


@contextlib.contextmanager
def quiet_rsl_rl() -> Iterator[None]:
    """Keep rsl-rl's prints (model dumps, 'Resolved observation sets' banners) off stdout; they are
    shown only if building the models fails."""
    captured = io.StringIO()
    try:
        with contextlib.redirect_stdout(captured):
            yield
    except BaseException:
        print(captured.getvalue(), end="")
        raise


def zero_observation(layout: ObservationLayout, n: int = 1) -> TensorDict:
    """A TensorDict with the observation groups' shapes (to build the models without an env)."""
    groups = {"policy": torch.zeros(n, layout.feature_dim)}
    if layout.image_shape:
        groups["image"] = torch.zeros(n, *layout.image_shape)
    return TensorDict(groups, batch_size=[n])


class PPOAgent:
    """The trained actor for evaluation: deterministic (mean) actions mapped onto the action bounds."""

    algo = "ppo"

    def __init__(self, config: dict, observation_space: gym.spaces.Dict, action_space: gym.Space):
        if not isinstance(action_space, gym.spaces.Box):
            raise ValueError("PPO (rsl-rl) needs continuous actions (actions: continuous)")
        cfg = copy.deepcopy(config["rsl_rl"])
        self.layout = ObservationLayout(observation_space)
        obs = zero_observation(self.layout)
        with quiet_rsl_rl():
            obs_groups = resolve_obs_groups(obs, cfg["obs_groups"], ["actor", "critic"])
            actor_class, actor_cfg = resolve_class(cfg["actor"])
            self.actor = actor_class(obs, obs_groups, "actor", int(np.prod(action_space.shape)), **actor_cfg)
        self.actor.eval()
        scale, offset = action_scaler(action_space)
        self.scale, self.offset = scale, offset

    @torch.no_grad()
    def act(self, obs: dict[str, np.ndarray], deterministic: bool = True) -> np.ndarray:
        td = to_tensordict(self.layout, obs)
        a = self.actor(td, stochastic_output=not deterministic).numpy()
        return self.offset + self.scale * np.clip(a, -1.0, 1.0)

    def load_state_dict(self, state: dict, inference_only: bool = True) -> None:
        if "actor_state_dict" not in state:
            raise CheckpointError("PPO state lacks 'actor_state_dict'")
        load_module_state(self.actor, state["actor_state_dict"], "PPO actor")

    def inference_state(self, state: dict) -> dict:
        return {"actor_state_dict": state["actor_state_dict"]}


def train(config: dict, run: Run, resume_state: dict | None = None) -> None:
    """PPO iterations until `run.total_steps` env steps."""
    cfg = copy.deepcopy(config["rsl_rl"])
    cfg.setdefault("save_interval", 10**9)
    env = RslRlVecEnv(make_training_env(config), reward_scale=float(config.get("reward_scale", 1.0)))
    try:
        _learn(env, cfg, run, resume_state, int(config.get("seed", 0)))
    finally:
        env.close()  # and its workers, also on Ctrl-C or an error


def _learn(env: RslRlVecEnv, cfg: dict, run: Run, resume_state: dict | None, seed: int) -> None:
    env.seed(seed + run.step)
    with warnings.catch_warnings(), quiet_rsl_rl():  # the duplicate-parameter warning of share_cnn_encoders,
        # fixed below
        warnings.filterwarnings("ignore", message="optimizer contains a parameter group with duplicate")
        runner = OnPolicyRunner(env, cfg, log_dir=None, device="cpu")  # no rsl-rl logger: we log ourselves
    params = list(runner.alg.optimizer.param_groups[0]["params"])
    unique = list({id(p): p for p in params}.values())
    if len(unique) < len(params):  # share_cnn_encoders lists the shared CNN twice: Adam would step it twice
        runner.alg.optimizer = type(runner.alg.optimizer)(unique, lr=runner.alg.learning_rate)
    if resume_state is not None:
        runner.alg.load(resume_state, None, strict=True)
    losses: dict[str, float] = {}
    update = runner.alg.update

    def update_and_keep_losses() -> dict[str, float]:
        losses.clear()
        losses.update(update())
        return losses

    runner.alg.update = update_and_keep_losses
    per_iteration = env.num_envs * cfg["num_steps_per_env"]
    iterations = math.ceil((run.total_steps - run.step) / per_iteration)
    rounded = run.step + iterations * per_iteration
    if rounded != run.total_steps:  # PPO learns from whole rollouts only
        print(f"PPO collects rollouts of {env.num_envs} envs x {cfg['num_steps_per_env']} steps = {per_iteration}: "
              f"training for {rounded:,} env steps (asked {run.total_steps:,})", flush=True)
        run.total_steps = run.bar.total = rounded
    for _ in range(iterations):
        runner.learn(1)
        run.add_steps(per_iteration, env.completed)
        env.completed.clear()
        run.scalars({**{f"{k}_loss": v for k, v in losses.items()}, "learning_rate": runner.alg.learning_rate,
                     "action_std": runner.alg.get_policy().output_std.mean().item()})
        if run.checkpoint_due():
            run.save("ppo", runner.alg.save())
    run.save("ppo", runner.alg.save(), periodic=False)
