"""Coverage across the wire: the share of kitchens that need a hand-over among those a level server streams
(started with its default generator config, as `cec up` starts it) to a client asking with the release
recipe's generator config, against the library's own draws with that config and the server's defaults.

    python benchmarks/streamed_coverage.py [--n 2000]

Then every other feature of the kitchens the same way, the stream against the library's draws with the same
config: the share of each kind, each tile's count, the kitchen's height and width and the seats' start
distance, each as the two means and their difference in standard errors (|z| above 3 in a feature: the
stream is not the library's distribution there).

Before the wire carried `handover_share` and `structure_weights` (594daee), a stream asked for the release
recipe got the server's defaults: the third line is what it trained on then.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=2000)
    args = ap.parse_args()

    import jax
    import numpy as np

    from cec.config import load_config
    from cec.levels.generator import generate_batch
    from cec.levels.kinds import Kind, classify
    from cec.training.config import TrainConfig
    from services.level_server.client import LevelClient
    from services.level_server.config import LevelServerConfig
    from services.level_server.server import ThreadedLevelServer

    recipe = load_config(TrainConfig, REPO / "configs/train/cec_overcooked_teacher.yaml").env.generator

    def share(levels: Any) -> float:
        return float(np.mean(np.asarray(jax.vmap(classify)(levels).kind) == Kind.HANDOVER))

    with ThreadedLevelServer(LevelServerConfig(port=0, metrics_port=-1, seed=700)) as server:
        client = LevelClient(server.address)
        streamed = [lv for _, lv in client.stream(seed=700000, batch_size=500, count=args.n, config=recipe)]
        default = [lv for _, lv in client.stream(seed=700001, batch_size=500, count=args.n)]
        client.close()
    local = jax.device_get(generate_batch(jax.random.PRNGKey(0), args.n, recipe))
    rows = (
        ("streamed, the recipe's config (handover_share 0.35)", np.mean([share(lv) for lv in streamed])),
        ("the library's own draws, the same config", share(local)),
        (
            "streamed, the server's defaults (what the wire gave before)",
            np.mean([share(lv) for lv in default]),
        ),
    )
    for name, value in rows:
        print(f"{name}: {value:.3f} of {args.n} kitchens need a hand-over")
    ours, theirs = _features(jax.tree.map(lambda *x: np.concatenate(x), *streamed)), _features(local)
    print(
        f"\nfeature: streamed | the library's draws | difference in standard errors ({args.n} kitchens each)"
    )
    for name in ours:
        a, b = ours[name], theirs[name]
        se = float(np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b)))
        z = (a.mean() - b.mean()) / se if se > 0 else 0.0
        print(f"{name:>24}: {a.mean():7.3f} | {b.mean():7.3f} | {z:+.1f}")
    return 0


def _features(levels: Any) -> dict[str, Any]:
    """Per kitchen: its kind (one-hot), each tile's count, height, width, the seats' start distance."""
    import jax
    import numpy as np

    from cec.levels.kinds import Kind, classify
    from cec.levels.level import Tile

    kind = np.asarray(jax.vmap(classify)(levels).kind)
    grid, pos, size = np.asarray(levels.grid), np.asarray(levels.agent_pos), np.asarray(levels.size)
    out = {f"kind: {k.label}": (kind == k).astype(float) for k in Kind}
    out |= {f"tiles: {t.name.lower()}": (grid == t).sum(axis=(1, 2)).astype(float) for t in Tile}
    out["height"], out["width"] = size[:, 0].astype(float), size[:, 1].astype(float)
    out["start distance"] = np.abs(pos[:, 0] - pos[:, 1]).sum(axis=1).astype(float)
    return out


if __name__ == "__main__":
    raise SystemExit(main())
