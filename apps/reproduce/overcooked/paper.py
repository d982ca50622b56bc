"""What the paper reports on Overcooked: its cross-play values as data
(`apps/reproduce/paper_overcooked.yaml`: read off its figures, and the few its text prints) and its human
study's ordering.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from apps.reproduce.overcooked.modes import LEVEL_SETS

PAPER_FILE = Path(__file__).parents[1] / "paper_overcooked.yaml"

#: The paper's human study (score with real people on Counter Circuit and Coordination Ring, its Q3).
HUMAN_STUDY = (
    "E3T ahead; CEC and CEC-Finetune next; FCP and IPPO behind (CEC ahead of FCP, p < 0.001). People "
    "rated CEC and CEC-Finetune the better partners on all seven subjective measures."
)


def paper_values(source: str = "figures") -> dict[str, dict[str, float]]:
    """{level set: {algorithm: the paper's XP}} as read off its figures (approximate), or `source="text"`:
    the few values its text prints (exact; CEC-E3T among them, which is not trained here)."""
    data = yaml.safe_load(PAPER_FILE.read_text())
    data = data.get("text", {}) if source == "text" else data
    return {s: dict(data.get(s, {})) for s in LEVEL_SETS}
