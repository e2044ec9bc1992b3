"""Quick behaviour check of a traffic-driver policy inside the training env (no FCD).

Per group (keepers, overtakers): lane changes per km, share of steps with lateral
acceleration above 1.5 m/s^2, share of following steps (leader within 150 m, speed > 5 m/s)
with a time headway below 1 s, mean speed as a share of the limit, losses per agent-hour.
The realism report (`behave report`) measures the same on populate's FCD; this one is for
iterating on training quickly.

    python benchmarks/traffic_check.py runs/.../checkpoints/best.pt --episodes 6
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from behaviors.learn.ddpg.checkpoint import load_actor
from behaviors.learn.env import make_env
from behaviors.traffic.lanes import TRAFFIC_OBS_SIZE


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--seed", type=int, default=100)
    parser.add_argument("--scenario", default="roads")
    args = parser.parse_args()
    torch.set_num_threads(1)
    actor = load_actor(args.checkpoint, expect_obs_dim=TRAFFIC_OBS_SIZE)
    env = make_env(args.scenario, behaviour="multi", overtakers=4, keepers=4, driver="traffic",
                   max_steps=args.steps, seed=args.seed)  # fmt: skip
    dt = env.config.step_length
    acc = {g: dict(km=0.0, changes=0, steps=0, hard_lat=0, follow=0, close=0, speed=0.0, lost=0)
           for g in (0.0, 1.0)}  # fmt: skip
    for episode in range(args.episodes):
        obs = env.reset_arrays(seed=args.seed + episode)
        while env.agents:
            with torch.inference_mode():
                actions = actor(torch.as_tensor(obs)).numpy()
            before = dict(zip(env.fleet.ids, env.fleet.own.lateral_speed.tolist(), strict=True))
            batch = env.step_arrays(actions)
            terms = batch.terms.as_dict()
            for g, stats in acc.items():
                rows = env.slot_behaviour[batch.slots] == g
                stats["km"] += float(batch.speed[rows].sum() * dt / 1000)
                stats["changes"] += int((terms["lane_change"][rows] < 0).sum())
                stats["lost"] += int((batch.collided | batch.off_track)[rows].sum())
            r, own = env.fleet.rows, env.fleet.own
            if len(r.ids) and own.around is not None:
                lat_acc = np.abs(own.lateral_speed - np.array([before[i] for i in r.ids])) / dt
                gap, speed = own.around.gap[:, 0], r.speed
                following = (gap < 150) & (speed > 5)
                for g, stats in acc.items():
                    rows = r.behaviour_id == g
                    stats["steps"] += int(rows.sum())
                    stats["speed"] += float((speed[rows] / r.frame.speed_limit[rows]).sum())
                    stats["hard_lat"] += int((lat_acc[rows] > 1.5).sum())
                    stats["follow"] += int(following[rows].sum())
                    stats["close"] += int((following & (gap < speed))[rows].sum())
            obs = env.live_obs
    env.close()
    print(f"{'group':10} {'LC/km':>7} {'lat>1.5':>8} {'THW<1s':>8} {'speed/lim':>9} {'loss/h':>7} {'km':>6}")
    for g, s in acc.items():
        hours = s["steps"] * dt / 3600
        print(f"{'overtaker' if g else 'keeper':10} {s['changes'] / max(s['km'], 1e-9):7.2f} "
              f"{s['hard_lat'] / max(s['steps'], 1):8.1%} {s['close'] / max(s['follow'], 1):8.1%} "
              f"{s['speed'] / max(s['steps'], 1):9.2f} {s['lost'] / max(hours, 1e-9):7.1f} "
              f"{s['km']:6.1f}")  # fmt: skip


if __name__ == "__main__":
    main()
