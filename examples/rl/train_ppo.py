"""Train Stable-Baselines3's PPO on `rodctl/ShapeServoRL-v0` for a few thousand steps.

    pip install -e ".[rl]"            # Stable-Baselines3 and torch (docs/install.md: the CPU build)
    python examples/rl/train_ppo.py --steps 4000

The environment (rodctl/rl.py, docs/rl.md) gives normalised float32 observations, actions in
[-1, 1] (scaled by `rod.max_step`) and reward minus the pixel error, plus `--success-bonus` on
convergence. The policy is SB3's "MultiInputPolicy" (the observation is a Dict). After
training, one deterministic episode is run and its result printed; the model is saved as
OUT/ppo_shapeservo.zip. A few thousand steps are a smoke run of the set-up, not a trained
controller: PPO needs far more to servo a rod (docs/rl.md).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym

import rodctl
from rodctl.config import load_config


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/default.yaml", help="experiment config")
    parser.add_argument("--set", dest="set_", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--steps", type=int, default=4000, help="environment steps to train")
    parser.add_argument("--n-steps", type=int, default=256, help="PPO rollout length")
    parser.add_argument("--success-bonus", type=float, default=100.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/ppo", help="folder of the saved model")
    args = parser.parse_args(argv)

    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)  # small networks: one thread is the fastest (docs/rl.md)
    cfg = load_config(args.config, ["logging.mcap=false", "logging.rerun=false", *args.set_])
    env = gym.make(rodctl.RL_ENV_ID, config=cfg, success_bonus=args.success_bonus)
    model = PPO(
        "MultiInputPolicy",
        env,
        n_steps=args.n_steps,
        batch_size=min(64, args.n_steps),
        seed=args.seed,
        device="cpu",
        verbose=0,
    )
    t0 = time.perf_counter()
    model.learn(total_timesteps=args.steps)
    train_s = time.perf_counter() - t0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / "ppo_shapeservo")

    obs, info = env.reset(seed=args.seed)
    done, steps, total = False, 0, 0.0
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(action)
        done, steps, total = terminated or truncated, steps + 1, total + float(reward)
    result = {
        "train_steps": args.steps,
        "train_s": round(train_s, 1),
        "episode_steps": steps,
        "episode_return": round(total, 1),
        "final_pixel_error": round(float(info["pixel_error"]), 2),
        "converged": bool(info["is_success"]),
        "model": str(out / "ppo_shapeservo.zip"),
    }
    for key, value in result.items():
        print(f"{key}: {value}")
    env.close()
    return result


if __name__ == "__main__":
    main()
