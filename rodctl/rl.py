"""The shape-servoing environment in the form RL libraries expect (docs/rl.md).

`rodctl.env.ShapeServoEnv` gives what the methods run on: (N, 2) float64 pixel arrays, metres and
radians, actions in metres bounded by `rod.max_step`, reward minus the pixel error. Fine for
control code, awkward for RL: Stable-Baselines3 warns about 2-D arrays and float64 actions, pixels
(150-400) sit beside metres (0.01), and an action space of +-0.01 against a Gaussian policy of
sigma 1 saturates every axis. The two environments here wrap it, so every episode is the same
one (same seeds, same physics, same camera) in another layout:

- `ShapeServoRLEnv`, registered as `rodctl/ShapeServoRL-v0`: a Dict of 1-D float32 arrays
  `centerline` (2N,), `target` (2N,), `gripper` (3,), `applied` (3,) and `extraction_ok`
  (Discrete(2)); for SB3's "MultiInputPolicy".
- `ShapeServoGoalEnv`, registered as `rodctl/ShapeServoGoal-v0`: the goal-conditioned form
  (`observation`, `achieved_goal` = the extracted centerline, `desired_goal` = the target,
  `compute_reward`), so that hindsight experience replay (SB3's `HerReplayBuffer`) can relabel
  goals.

Options (keyword arguments, also through `gymnasium.make`):
    normalize_actions (True): the action space is [-1, 1]^3 (float32), scaled by `rod.max_step`
        per axis; False: metres and radians, bounded by `rod.max_step`.
    normalize_observations (True): pixels as (u - width/2, v - height/2) / (max(width,
        height)/2), about [-1, 1] in the image; gripper pose mapped from the workspace to
        [-1, 1]; `applied` in units of `rod.max_step`. False: pixels, metres and radians.
    success_bonus (0.0): added to the reward of the step that converges (pixel error below
        `run.pixel_tolerance`).

Reward: minus the pixel error (mean point distance to the target, px; a lost frame costs the
image diagonal), plus the bonus on convergence. `info` is the core environment's plus
`is_success` (converged: SB3 logs its rate) and `extraction_ok`, without the camera frame
(`image`; `render()` returns it). The core environment is
`env.core`; its observation of the last step, float64 and unchanged, is `env.core_observation`.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from rodctl.env import ShapeServoEnv

F32 = np.float32


class ShapeServoRLEnv(gym.Env):
    """`ShapeServoEnv` with flat float32 observations, optional normalisation and a success
    bonus (module doc).

    Args:
        config: as `ShapeServoEnv` (an `ExperimentConfig`, a mapping, a YAML path or None).
        render_mode: None or "rgb_array" (the camera frame).
        normalize_actions: actions in [-1, 1] scaled by `rod.max_step`.
        normalize_observations: observations scaled to about [-1, 1].
        success_bonus: reward added on the converging step (>= 0).
    """

    metadata = ShapeServoEnv.metadata

    def __init__(
        self,
        config: Any = None,
        render_mode: str | None = None,
        *,
        normalize_actions: bool = True,
        normalize_observations: bool = True,
        success_bonus: float = 0.0,
    ) -> None:
        for name, flag in (
            ("normalize_actions", normalize_actions),
            ("normalize_observations", normalize_observations),
        ):
            if not isinstance(flag, bool | np.bool_):  # "no" would be read as True
                raise TypeError(f"{name} must be True or False, got {flag!r}")
        if not (math.isfinite(success_bonus) and success_bonus >= 0.0):
            raise ValueError(f"success_bonus must be a finite number >= 0, got {success_bonus!r}")
        self.core = ShapeServoEnv(config, render_mode=render_mode)
        self.render_mode = render_mode
        self.normalize_actions = bool(normalize_actions)
        self.normalize_observations = bool(normalize_observations)
        self.success_bonus = float(success_bonus)
        self.core_observation: dict[str, Any] | None = None
        self._set_spaces()

    # --- layout --------------------------------------------------------------------------------

    def _set_spaces(self) -> None:
        """The spaces of the core's config; each bound is the core's bound through the same
        (monotone) transform as the values, so a core observation inside the core's space is
        inside this one."""
        core, cfg = self.core, self.core.cfg
        size = np.array([cfg.camera.width, cfg.camera.height], dtype=float)
        self._centre, self._px_scale = size / 2.0, float(size.max()) / 2.0
        ws = cfg.rod.workspace
        lo = np.array([ws.x_limits[0], ws.y_limits[0], ws.theta_limits[0]], dtype=float)
        hi = np.array([ws.x_limits[1], ws.y_limits[1], ws.theta_limits[1]], dtype=float)
        self._max_step = np.asarray(cfg.rod.max_step, dtype=float)
        self._q = int(getattr(core, "q", 3))
        if self._q == 6:  # dual-arm: the x0 end's workspace and speed limit follow the gripper's
            cws = cfg.rod.clamp_arm.workspace
            lo = np.concatenate([lo, [cws.x_limits[0], cws.y_limits[0], cws.theta_limits[0]]])
            hi = np.concatenate([hi, [cws.x_limits[1], cws.y_limits[1], cws.theta_limits[1]]])
            self._max_step = np.concatenate(
                [self._max_step, np.asarray(cfg.rod.clamp_arm.max_step, dtype=float)]
            )
        self._ws_mid, self._ws_half = (lo + hi) / 2.0, (hi - lo) / 2.0
        self._lost_frame_cost = float(np.hypot(*size))
        self._tolerance = float(cfg.run.pixel_tolerance)
        n = cfg.camera.points
        src = core.observation_space
        assert isinstance(src, spaces.Dict)  # ShapeServoEnv's observations are a Dict
        if self.normalize_observations:
            # (2M - c) / S < 4 and (-M - c) / S > -4 for M = max(width, height) = 2 S.
            pixels = spaces.Box(-4.0, 4.0, (2 * n,), dtype=F32)
        else:
            box = _box(src["centerline"])
            pixels = spaces.Box(float(box.low.min()), float(box.high.max()), (2 * n,), dtype=F32)
        g, a = _box(src["gripper"]), _box(src["applied"])
        self._spaces = {
            "centerline": pixels,
            "target": pixels,
            "gripper": spaces.Box(self._gripper(g.low), self._gripper(g.high), dtype=F32),
            "applied": spaces.Box(self._applied(a.low), self._applied(a.high), dtype=F32),
            "extraction_ok": spaces.Discrete(2),
        }
        self.observation_space = spaces.Dict(self._spaces)
        if self.normalize_actions:
            self.action_space = spaces.Box(-1.0, 1.0, (self._q,), dtype=F32)
        else:
            limit = self._max_step.astype(F32)
            self.action_space = spaces.Box(-limit, limit, dtype=F32)

    def _pixels(self, points: np.ndarray, ok: bool) -> np.ndarray:
        if not ok:
            return np.zeros(points.size, dtype=F32)  # a lost frame: zeros, as the core says
        if self.normalize_observations:
            points = (points - self._centre) / self._px_scale
        return np.asarray(points, dtype=F32).reshape(-1)

    def _gripper(self, pose: np.ndarray) -> np.ndarray:
        out = (pose - self._ws_mid) / self._ws_half if self.normalize_observations else pose
        return np.asarray(out, dtype=F32)

    def _applied(self, du: np.ndarray) -> np.ndarray:
        out = du / self._max_step if self.normalize_observations else du
        return np.asarray(out, dtype=F32)

    def _convert(self, obs: dict[str, Any]) -> dict[str, Any]:
        self.core_observation = obs
        ok = bool(obs["extraction_ok"])
        return {
            "centerline": self._pixels(obs["centerline"], ok),
            "target": self._pixels(obs["target"], True),
            "gripper": self._gripper(obs["gripper"]),
            "applied": self._applied(obs["applied"]),
            "extraction_ok": int(obs["extraction_ok"]),
        }

    def _move(self, action: np.ndarray) -> np.ndarray:
        """The pose increment [dx, dy, dtheta] an action asks for."""
        a = np.asarray(action, dtype=float).reshape(self._q)
        return np.clip(a, -1.0, 1.0) * self._max_step if self.normalize_actions else a

    # --- Gymnasium API -------------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start an episode of the core environment (same `seed` and `options`)."""
        super().reset(seed=seed)
        obs, info = self.core.reset(seed=seed, options=options)
        if options and "config" in options:
            self._set_spaces()
        return self._layout(self._convert(obs)), self._info(info, converged=False)

    def step(self, action: np.ndarray) -> tuple[dict[str, Any], float, bool, bool, dict]:
        """Move by `action` (see `normalize_actions`), as `ShapeServoEnv.step`."""
        obs, reward, terminated, truncated, info = self.core.step(self._move(action))
        converged = bool(terminated and not info["diverged"])
        info = self._info(info, converged=converged)
        out = self._layout(self._convert(obs))
        return out, self._reward(out, reward, converged, info), terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """The last camera frame, (H, W, 3) uint8 RGB (render_mode "rgb_array")."""
        return self.core.render()

    def close(self) -> None:
        self.core.close()

    # --- what the goal-conditioned form changes ------------------------------------------------

    def _layout(self, obs: dict[str, Any]) -> dict[str, Any]:
        return obs

    def _info(self, info: dict[str, Any], *, converged: bool) -> dict[str, Any]:
        ok = self.core.frame is not None and bool(self.core.frame.ok)
        # Not the camera frame: replay buffers that keep infos (HER's) would hold every image.
        kept = {k: v for k, v in info.items() if k != "image"}
        return {**kept, "is_success": converged, "extraction_ok": ok}

    def _reward(self, obs: dict, core_reward: float, converged: bool, info: dict) -> float:
        return float(core_reward) + (self.success_bonus if converged else 0.0)


class ShapeServoGoalEnv(ShapeServoRLEnv):
    """The goal-conditioned form: observation, achieved_goal, desired_goal, compute_reward.

    `observation` is [centerline (2N), gripper (3), applied (3), extraction_ok (1)] in one
    float32 vector with one bound for all (the loosest of its parts); `achieved_goal` the
    extracted centerline and `desired_goal` the target, (2N,) each, in the observation's units.
    The reward is `compute_reward(achieved_goal, desired_goal, info)`: minus the mean point
    distance in pixels, plus `success_bonus` below `run.pixel_tolerance`; a lost frame
    (`info["extraction_ok"]` False) costs the image diagonal. It is computed from the float32
    goals, so it can differ from the core's `info["pixel_error"]` by about 1e-4 px.
    """

    def _set_spaces(self) -> None:
        super()._set_spaces()
        parts = [_box(self._spaces[k]) for k in ("centerline", "gripper", "applied")]
        low = min(float(p.low.min()) for p in parts + [spaces.Box(0.0, 1.0)])
        high = max(float(p.high.max()) for p in parts + [spaces.Box(0.0, 1.0)])
        size = sum(p.shape[0] for p in parts) + 1
        pixels = self._spaces["centerline"]
        self.observation_space = spaces.Dict(
            {
                "observation": spaces.Box(low, high, (size,), dtype=F32),
                "achieved_goal": pixels,
                "desired_goal": pixels,
            }
        )

    def _layout(self, obs: dict[str, Any]) -> dict[str, Any]:
        flat = np.concatenate(
            [obs["centerline"], obs["gripper"], obs["applied"], [F32(obs["extraction_ok"])]]
        ).astype(F32)
        return {
            "observation": flat,
            "achieved_goal": obs["centerline"].copy(),
            "desired_goal": obs["target"].copy(),
        }

    def _reward(self, obs: dict, core_reward: float, converged: bool, info: dict) -> float:
        return float(self.compute_reward(obs["achieved_goal"], obs["desired_goal"], info))

    def compute_reward(self, achieved_goal: Any, desired_goal: Any, info: Any) -> Any:
        """The reward of reaching `achieved_goal` when `desired_goal` was asked for.

        Vectorised: goals of shape (2N,) or (B, 2N); `info` a dict, a sequence or array of B
        dicts (as SB3's `HerReplayBuffer` passes), or None (every frame seen).

        Returns:
            A float for one pair, else a (B,) array.
        """
        a = np.asarray(achieved_goal, dtype=np.float64)
        d = np.asarray(desired_goal, dtype=np.float64)
        diff = (a - d).reshape(*a.shape[:-1], -1, 2)
        if self.normalize_observations:
            diff = diff * self._px_scale
        dist = np.linalg.norm(diff, axis=-1).mean(axis=-1)
        reward = -dist + self.success_bonus * (dist < self._tolerance)
        ok = np.broadcast_to(_frames_seen(info), np.shape(dist))
        reward = np.where(ok, reward, -self._lost_frame_cost)
        return float(reward) if np.ndim(reward) == 0 else reward


def _box(space: spaces.Space) -> spaces.Box:
    """A part of the observation space that is a Box (the pixels, the gripper, the moves)."""
    assert isinstance(space, spaces.Box)
    return space


def _frames_seen(info: Any) -> np.ndarray | bool:
    """`extraction_ok` of one info dict, of each of a batch of them, or True for None."""
    if info is None:
        return True
    if isinstance(info, dict):
        return bool(info.get("extraction_ok", True))
    return np.array([bool(i.get("extraction_ok", True)) if i else True for i in info])
