"""Config files are read in bounded memory and time, and every bad one ends in a clear error naming the
file (`cec train --config ...`, exit 2), never a hang, a MemoryError or a traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from cec.config import CONFIG_MAX_BYTES, ConfigError, load_config
from cec.training.config import TrainConfig

REPO = Path(__file__).resolve().parents[3]


def _fifo(tmp_path: Path) -> Path:
    path = tmp_path / "fifo.yaml"
    os.mkfifo(path)  # reading it would block forever
    return path


def _big(tmp_path: Path) -> Path:
    path = tmp_path / "big.yaml"
    path.write_text("# padding\n" * (CONFIG_MAX_BYTES // 10 + 10))
    return path


def _deep(tmp_path: Path) -> Path:
    path = tmp_path / "deep.yaml"
    path.write_text("a: " + "[" * 10_000 + "]" * 10_000 + "\n")
    return path


CASES = {
    "folder": (lambda tmp: tmp, "is a folder; give the file inside it"),
    "fifo": (_fifo, "is not a regular file"),
    "too big": (_big, "is larger than"),
    "nested": (_deep, "nests too deeply"),
    "missing": (lambda tmp: tmp / "nope.yaml", "does not exist"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_bad_config_file_is_refused_with_its_name_and_cause(tmp_path: Path, case: str) -> None:
    make, message = CASES[case]
    path = make(tmp_path)
    with pytest.raises(ConfigError, match=message) as info:
        load_config(TrainConfig, path)
    assert str(path) in str(info.value)


def test_cec_train_exits_2_on_a_fifo_config_instead_of_hanging(tmp_path: Path) -> None:
    path = _fifo(tmp_path)
    cmd = [sys.executable, "-m", "apps.cli", "train", "--config", str(path)]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "is not a regular file" in proc.stderr and "Traceback" not in proc.stderr
