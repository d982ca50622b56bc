"""What `cec partners` plays and where it keeps it: one cross-play per question (as `cec eval` plays it, in
this process), kept compressed in the command's `--out` folder and read from there on the next call; the
kitchens' validation proxies; the shipped zoo rewritten in place.
"""

from __future__ import annotations

import bz2
import logging
from collections.abc import Callable, Sequence
from pathlib import Path

import yaml

from cec.agents.zoo import ZooEntry, load_zoo
from cec.config import ConfigError
from cec.evaluation.results import EpisodeTable, read_csv, write_csv

log = logging.getLogger("cec.partners")
#: The README's protocol: 400-step episodes, sampled actions, common random numbers; 4 per seat order.
STEPS, EPISODES = 400, 4
#: The algorithm labels of the human proxies in the tables: the test proxies (shipped, `hp_<kitchen>`) and
#: the validation proxies (`bc_<kitchen>`, cloned by `cec humans bc` from the train games' players).
PROXY, BC = "human_proxy", "bc_proxy"


class Tables:
    """The command's tables in `folder` (`<name>.csv.bz2`, the bytes of `cec eval`'s CSV compressed): each
    played once, then read; delete one (or give another `--out`) to play it again."""

    def __init__(self, folder: Path, say: Callable[[str], None]) -> None:
        self.folder, self.say = folder, say

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.csv.bz2"

    def get(
        self,
        name: str,
        entries: Callable[[], Sequence[ZooEntry]],
        levels: str,
        *,
        episodes: int,
        steps: int,
        pairs: str = "all",
    ) -> EpisodeTable:
        """The table `name`: read from its file, or `entries()` (built only then) played on `levels` and
        written, the entries that cannot be loaded recorded as skipped (as `cec eval` does)."""
        from cec.agents.policy import load_policies
        from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels

        path = self.path(name)
        if path.exists():
            self.say(f"reusing {path}")
            return read_csv(path)
        config = EvalConfig(levels=levels, episodes=episodes, max_steps=steps, pairs=pairs)
        policies, skipped = load_policies(entries())
        for s in skipped:
            self.say(f"skipping {s.name}: {s.reason}")
        self.say(f"playing {name}: {len(policies)} policies on {levels}, {steps}-step episodes ({pairs})")
        played = crossplay(
            policies, eval_levels("overcooked", levels), config, skipped=skipped, progress=log.info
        )
        self.folder.mkdir(parents=True, exist_ok=True)
        plain = write_csv(played, self.folder / f".{name}.csv")
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_bytes(bz2.compress(plain.read_bytes(), 9))
        plain.unlink()
        tmp.replace(path)
        return read_csv(path)


def validation_proxy(proxies: Path, kitchen: str) -> ZooEntry:
    """`bc_<kitchen>` of `cec humans bc`'s zoo as the validation proxy (algorithm `BC`, seat in `kitchen`);
    `ConfigError` naming the fix when the zoo, the entry or its checkpoint is missing: it is what chooses,
    so nothing is played without it."""
    from cec.agents.policy import resolve_checkpoint
    from cec.checkpoints import CheckpointError

    clone = f"cec humans import && cec humans bc --kitchens {kitchen} --out {proxies.parent}"
    if not proxies.is_file():
        raise ConfigError(
            f"--proxies {str(proxies)!r} does not exist: clone the validation proxies ({clone}) or give "
            "--proxies the zoo.yaml of `cec humans bc`"
        )
    found = [e for e in load_zoo(proxies) if e.name == f"bc_{kitchen}"]
    if not found:
        raise ConfigError(f"{proxies} has no bc_{kitchen}, the validation proxy that chooses: {clone}")
    bc = found[0]
    if bc.scripted is None:
        try:
            resolve_checkpoint(bc.checkpoint)
        except CheckpointError as err:
            raise ConfigError(f"{proxies}: bc_{kitchen}: {err}; clone it again: {clone}") from err
    return ZooEntry(bc.name, bc.checkpoint, BC, 0, (kitchen,), bc.sha256, bc.scripted)


def replace_entries(zoo: Path, entries: Sequence[dict]) -> None:
    """`entries` into the zoo manifest `zoo` in place of those of the same names (new names at the end), its
    comment kept; written to a temporary file, then renamed."""
    doc = yaml.safe_load(zoo.read_text())
    new = {e["name"]: e for e in entries}
    policies = [new.pop(e["name"], e) for e in doc["policies"]]
    doc["policies"] = policies + list(new.values())
    header = "".join(line + "\n" for line in zoo.read_text().splitlines() if line.startswith("#"))
    tmp = zoo.with_name(zoo.name + ".tmp")
    tmp.write_text(header + yaml.safe_dump(doc, sort_keys=False))
    tmp.replace(zoo)


def write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def check_play_sizes(episodes: int, max_steps: int) -> None:
    """`--episodes` and `--max-steps` within their ranges, refused by name before anything is played."""
    for flag, value, top in (("--episodes", episodes, 1000), ("--max-steps", max_steps, 100_000)):
        if not 1 <= value <= top:
            raise ConfigError(f"{flag} must be in 1..{top}, got {value}")
