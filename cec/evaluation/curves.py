"""Learning curves from run directories: the `metrics.csv` every training run writes, as one PNG.

    plot_learning_curves({"egocentric MLP": "runs/probes/p3"}, "curves.png")

Each panel is one metric against env steps (per seed): the team return and the unscaled shaped return
per training episode, and the policy entropy. Curves are smoothed with a trailing mean over `smooth`
updates; the raw rows stay in the run directories.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cec.evaluation.plotting import distinct_colours, pyplot
from cec.evaluation.results import ResultsError, cap, open_text, stored

#: The most values (rows x columns) of one run's metrics table read (a value costs about 60 bytes parsed;
#: the committed ones hold under 1 MB of text); `CEC_METRICS_MAX_CELLS` raises it.
METRICS_MAX_CELLS = 4_000_000

#: (metrics.csv column, panel title)
PANELS: tuple[tuple[str, str], ...] = (
    ("mean_return", "team return per training episode"),
    ("mean_shaped_return", "shaped return per training episode (unscaled)"),
    ("entropy", "policy entropy"),
)


def metrics_file(run_dir: str | Path) -> Path:
    """A run directory's `metrics.csv`, or its `metrics.csv.gz` where a committed run kept only that."""
    return stored(Path(run_dir) / "metrics.csv")


def read_metrics_csv(run_dir: str | Path) -> list[dict[str, Any]]:
    """The rows of a run directory's `metrics.csv` (`metrics_file`): numbers as floats, blanks as None.
    Read through the results tables' bounded reader (`open_text`), at most `METRICS_MAX_CELLS` values
    (`CEC_METRICS_MAX_CELLS`); `ResultsError` naming the file and line of a row csv cannot read."""
    path = metrics_file(run_dir)
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist: give a training run directory")
    limit, cells = cap("METRICS_MAX_CELLS", METRICS_MAX_CELLS), 0
    rows: list[dict[str, Any]] = []
    try:
        with open_text(path, "metrics file") as f:
            reader = csv.DictReader(f)
            try:
                for row in reader:
                    cells += len(row)
                    if cells > limit:
                        raise ResultsError(
                            f"{path}, line {reader.line_num}: more than {limit:,} values, the most read of "
                            f"a metrics file ({__name__}.METRICS_MAX_CELLS); raise the cap if the file is "
                            "genuine: CEC_METRICS_MAX_CELLS=N in the environment"
                        )
                    if None in row:  # DictReader's key for the fields past the header's
                        raise ResultsError(
                            f"{path}, line {reader.line_num}: the row has more fields than the header"
                        )
                    rows.append({k: _value(v) for k, v in row.items()})
            except (csv.Error, UnicodeDecodeError) as err:  # a field over csv's limit, bytes not UTF-8
                raise ResultsError(f"{path}, line {reader.line_num + 1}: {err}") from None
    except (OSError, EOFError) as err:  # bad gzip or bzip2 data, a cut-off stream
        raise ResultsError(f"{path} cannot be read as a metrics file: {err}") from err
    return rows


def _value(text: str | None) -> Any:
    if text in ("", None):
        return None
    try:
        return float(text)
    except ValueError:
        return text


def read_curve(run_dir: str | Path, column: str) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """{seed: (env_steps, values)} of one metric of a run directory, in update order."""
    by_seed: dict[int, list[tuple[float, float]]] = {}
    for row in read_metrics_csv(run_dir):
        value = row.get(column)
        if value is not None:
            by_seed.setdefault(int(row["seed"]), []).append((float(row["env_steps"]), float(value)))
    return {s: (np.array([x for x, _ in v]), np.array([y for _, y in v])) for s, v in by_seed.items()}


def trailing_mean(values: np.ndarray, window: int) -> np.ndarray:
    """The mean of each value and the `window - 1` before it (fewer at the start)."""
    if window <= 1 or len(values) == 0:
        return values
    sums = np.cumsum(np.insert(values, 0, 0.0))
    idx = np.arange(1, len(values) + 1)
    lo = np.maximum(idx - window, 0)
    return (sums[idx] - sums[lo]) / (idx - lo)


def plot_learning_curves(
    runs: Mapping[str, str | Path | Sequence[str | Path]],
    path: str | Path,
    *,
    smooth: int = 20,
    title: str = "",
    panels: Sequence[tuple[str, str]] = PANELS,
) -> Path:
    """One PNG with a panel per metric and a line per (run, seed), labelled by the keys of `runs` (a key
    may name several run directories, e.g. one per seed: they share its colour)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(5.0 * len(panels), 3.8), squeeze=False)
    for (label, dirs), color in zip(runs.items(), distinct_colours(len(runs)), strict=True):
        dirs = [dirs] if isinstance(dirs, str | Path) else list(dirs)
        for ax, (column, panel_title) in zip(axes[0], panels, strict=True):
            curves = [c for d in dirs for _, c in sorted(read_curve(d, column).items())]
            for i, (steps, values) in enumerate(curves):
                ax.plot(
                    steps / 1e6,
                    trailing_mean(values, smooth),
                    color=color,
                    lw=1.2,
                    alpha=1.0 if i == 0 else 0.6,
                    label=label if i == 0 else None,
                )
            ax.set_title(panel_title, fontsize=9)
            ax.set_xlabel("env steps per seed (millions)")
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7, loc="upper left")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
