"""FCP vs IPPO in cross-play with unseen partners on Dual Destination (fixed task, `small` network, CPU).

    python research/analyses/fcp_dual_destination.py                # ~10 minutes on one CPU core
    python research/analyses/fcp_dual_destination.py --partial-obs  # the 3x3-view variant (paper appendix)

The paper's ordering to check: a Fictitious Co-Play agent, trained against a frozen population of IPPO
self-play seeds (each at its first, middle and last milestone), cooperates better with IPPO seeds it never
met than those IPPO seeds cooperate with each other.

1. IPPO: `configs/train/dd_ippo_quick.yaml` with `--pop-seeds + --eval-seeds` seeds in one vmapped run,
   milestones at 0, 0.5 and 1 of the run. The first `--pop-seeds` seeds form FCP's population; the others
   are the unseen partners.
2. FCP: `configs/train/dd_fcp_quick.yaml` (same budget and PPO settings) with that population, `--fcp-seeds`
   seeds.
3. Cross-play (`cec.evaluation.crossplay`, sampled actions, common random numbers, both seat orders,
   `--episodes` episodes per game): every FCP seed and every unseen IPPO seed with every unseen IPPO seed.
   Reported as the oracle-normalised score return / (2 x 100) (the oracle reaches 0.955):
   IPPO XP = unseen IPPO seeds with each other (distinct seeds), IPPO SP = each with itself,
   FCP XP = FCP with the unseen IPPO seeds. The ratio printed is FCP XP / IPPO XP.
"""

from __future__ import annotations

import argparse
import datetime
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from apps.machine import machine_info
from cec.agents.policy import load_policy
from cec.agents.zoo import ZooEntry
from cec.checkpoints import code_version
from cec.config import from_dict, read_config
from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels
from cec.training.config import TrainConfig
from cec.training.run import train

ROOT = Path(__file__).resolve().parents[2]


def preset(file: str, partial_obs: bool, **changes: object) -> TrainConfig:
    data = read_config(ROOT / "configs/train" / file)  # the preset with its `base:` chain
    data.update(changes)
    data["env"] = {**data["env"], "dual_destination": {"partial_obs": partial_obs}}
    return from_dict(TrainConfig, data)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pop-seeds", type=int, default=4)
    parser.add_argument("--eval-seeds", type=int, default=4)
    parser.add_argument("--fcp-seeds", type=int, default=2)
    parser.add_argument("--steps", type=int, default=512_000, help="env steps per seed (both algorithms)")
    parser.add_argument("--episodes", type=int, default=32)
    parser.add_argument("--partial-obs", action="store_true", help="3x3 view (the paper's POMDP variant)")
    parser.add_argument("--work", help="directory for the runs (default: a temporary one)")
    parser.add_argument(
        "--out", help="result JSON (default: research/results/fcp_dual_destination_<obs>_cpu.json)"
    )
    args = parser.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix="fcp_dd_"))
    obs = "partial_obs" if args.partial_obs else "full_obs"
    out = Path(args.out or ROOT / f"research/results/fcp_dual_destination_{obs}_cpu.json")
    result: dict = {"date": datetime.date.today().isoformat(), "machine": machine_info(),
                    "git": code_version(short=True), "args": vars(args)}  # fmt: skip

    n_ippo = args.pop_seeds + args.eval_seeds
    t0 = time.perf_counter()
    ippo = preset("dd_ippo_quick.yaml", args.partial_obs, num_seeds=n_ippo, total_env_steps=args.steps,
                  run_dir=str(work), name="ippo",
                  checkpoint={"every_updates": 0, "milestones": [0.0, 0.5, 1.0]})  # fmt: skip
    print(f"training IPPO: {n_ippo} seeds x {args.steps:,} steps", flush=True)
    ippo_dir = train(ippo, progress=True).run_dir
    result["ippo_train_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    population = [{"run": str(ippo_dir), "seeds": list(range(args.pop_seeds)),
                   "checkpoints": ["first", "middle", "last"]}]  # fmt: skip
    partner = {"kind": "fcp", "population": population}
    fcp = preset("dd_fcp_quick.yaml", args.partial_obs, num_seeds=args.fcp_seeds, seed=100,
                 total_env_steps=args.steps, run_dir=str(work), name="fcp", partner=partner)  # fmt: skip
    print(f"training FCP: {args.fcp_seeds} seeds x {args.steps:,} steps, population of "
          f"{args.pop_seeds} seeds x 3 milestones", flush=True)  # fmt: skip
    fcp_dir = train(fcp, progress=True).run_dir
    result["fcp_train_s"] = time.perf_counter() - t0

    unseen = [load_policy(ZooEntry(f"ippo_s{s}", str(ippo_dir), "ippo", s)) for s in
              range(args.pop_seeds, n_ippo)]  # fmt: skip
    fcps = [
        load_policy(ZooEntry(f"fcp_s{s}", str(fcp_dir), "fcp", s)) for s in range(100, 100 + args.fcp_seeds)
    ]
    t0 = time.perf_counter()
    table = crossplay([*unseen, *fcps], eval_levels("dual_destination", "fixed"),
                      EvalConfig(levels="fixed", episodes=args.episodes))  # fmt: skip
    result["crossplay_s"] = time.perf_counter() - t0
    score = table.returns / (2 * 100)
    a, b = table.policy_a.astype(str), table.policy_b.astype(str)
    is_ippo_a, is_ippo_b = np.char.startswith(a, "ippo"), np.char.startswith(b, "ippo")
    ippo_xp = score[is_ippo_a & is_ippo_b & (a != b)]
    ippo_sp = score[is_ippo_a & (a == b)]
    fcp_xp = score[(np.char.startswith(a, "fcp") & is_ippo_b) | (is_ippo_a & np.char.startswith(b, "fcp"))]
    fcp_sp = score[np.char.startswith(a, "fcp") & (a == b)]

    def summary(x: np.ndarray) -> dict[str, float]:
        return {"mean": float(x.mean()), "sem": float(x.std(ddof=1) / np.sqrt(len(x))), "episodes": len(x)}

    result.update(ippo_xp=summary(ippo_xp), ippo_sp=summary(ippo_sp), fcp_xp=summary(fcp_xp),
                  fcp_sp=summary(fcp_sp))  # fmt: skip
    result["fcp_xp_over_ippo_xp"] = float(fcp_xp.mean() / ippo_xp.mean())
    result["fcp_xp_minus_ippo_xp"] = float(fcp_xp.mean() - ippo_xp.mean())
    per_pair = {}
    for pa in sorted(set(a)):
        for pb in sorted(set(b)):
            m = (a == pa) & (b == pb)
            if m.any():
                per_pair[f"{pa}|{pb}"] = float(score[m].mean())
    result["per_pair"] = per_pair
    for name in ("ippo_sp", "ippo_xp", "fcp_xp", "fcp_sp"):
        s = result[name]
        print(f"{name:8s} {s['mean']:.3f} +- {s['sem']:.3f} (normalised, {s['episodes']} episodes)")
    print(f"FCP XP / IPPO XP = {result['fcp_xp_over_ippo_xp']:.2f}, difference "
          f"{result['fcp_xp_minus_ippo_xp']:+.3f} (unseen IPPO partners)")  # fmt: skip
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
