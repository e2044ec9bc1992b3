"""The recipe of the shipped styled.pt: demonstrations of the styled driver's teacher on the training
roads, then an actor fitted to them (behaviors/learn/imitation.py).

    python benchmarks/make_styled.py --episodes 160 --seed 1          # collect, fit, write styled.pt
    python benchmarks/make_styled.py --episodes 10 --seed 2 --collect-only   # more, in pieces
    python benchmarks/make_styled.py --fit-only --demos runs/styled/demos_seed1.npz --demos ...

Collection is the slow part (about 15 s per 500-step episode of 8 agents on one core) and is kept in
an .npz beside the run, so that fitting can be repeated alone.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

from behaviors.learn.imitation import Demonstrations, collect, fit_actor, save_styled, steer_agreement
from behaviors.learn.policy import PRETRAINED

HIDDEN = (256, 256)
"""As traffic.pt's actor."""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--episodes", type=int, default=160)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--runs", type=Path, default=Path("runs/styled"))
    parser.add_argument("--demos", type=Path, action="append", help="demonstrations to fit (repeatable)")
    parser.add_argument("--fit-only", action="store_true", help="fit --demos files; collect nothing")
    parser.add_argument("--collect-only", action="store_true", help="collect and keep; fit nothing")
    parser.add_argument("--out", type=Path, default=PRETRAINED / "styled.pt")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    args.runs.mkdir(parents=True, exist_ok=True)
    files = list(args.demos or [])
    if not args.fit_only:
        start = time.perf_counter()
        demos = collect(args.episodes, args.seed)
        path = args.runs / f"demos_seed{args.seed}.npz"
        np.savez_compressed(path, obs=demos.obs, actions=demos.actions)
        took = time.perf_counter() - start
        print(f"{len(demos)} agent-steps from {args.episodes} episodes in {took:.0f} s -> {path}")
        files.append(path)
    if args.collect_only:
        return 0
    if not files:
        parser.error("nothing to fit: give --demos or collect")
    parts = [np.load(f) for f in files]
    demos = Demonstrations(
        np.concatenate([p["obs"] for p in parts]), np.concatenate([p["actions"] for p in parts])
    )
    wishes = np.rint(demos.actions[:, 0])
    print("steer labels: " + ", ".join(f"{int(w):+d}: {int((wishes == w).sum())}" for w in (-1, 0, 1)))
    start = time.perf_counter()
    actor, losses = fit_actor(demos, HIDDEN, args.epochs, args.seed)
    overall, on_changes = steer_agreement(actor, demos)
    print(f"fitted in {time.perf_counter() - start:.0f} s: loss {losses[0]:.4f} -> {losses[-1]:.4f}, "
          f"lane wish as the teacher's in {100 * overall:.2f}% of agent-steps, "
          f"{100 * on_changes:.1f}% of those heading for another lane")  # fmt: skip
    sources = ", ".join(str(f) for f in files)
    note = f"{len(demos)} agent-steps of the teacher ({sources}), {args.epochs} epochs"
    save_styled(args.out, actor, demos, args.seed, note)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
