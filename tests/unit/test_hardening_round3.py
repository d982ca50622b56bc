"""Third hardening round (issue 63) for the library and the `cec` commands that need no service: names
become paths only through `cec.paths` (a shared zoo manifest naming `../victim` removed that folder), a
checkpoint never replaces a folder that is not one, result tables are read through one bounded
decompressing reader with strict rows, and overrides are bounded in depth like files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from cec import checkpoints
from cec.config import ConfigError, load_config
from cec.paths import UnsafeNameError, named_path, safe_name

REPO = Path(__file__).resolve().parents[2]


def _cec(*args: str, timeout: float = 180) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "apps.cli", *args]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=timeout)


# ---- names become paths through one function ------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "cause"),
    [
        ("../victim", "path separator"),
        ("/home/me", "path separator"),
        ("a\\b", "path separator"),
        ("..", "names a folder itself"),
        (".", "names a folder itself"),
        ("", "it is empty"),
        ("a\nb", "control character"),
        (".lock", "starts with '.'"),
        ("run.tmp", "temporary files"),
        ("CON", "reserved device name"),
        ("nul.txt", "reserved device name"),
        ("x" * 256, "longer than 255 bytes"),
        (3, "not a string"),
    ],
)
def test_a_name_that_would_leave_its_folder_is_refused_naming_the_cause_and_the_fix(name, cause, tmp_path):
    with pytest.raises(UnsafeNameError, match=cause) as info:
        named_path(tmp_path, name, "policy name", fix="rename it")
    assert str(info.value).startswith("policy name ") and str(info.value).endswith("; rename it")


def test_plain_names_pass_unchanged(tmp_path):
    for name in ("cec-s0", "ippo_cramped_room-s1", "a.b", "console", "überkoch", "x" * 255):
        assert safe_name(name, "name") == name
        assert named_path(tmp_path, name, "name").parent == tmp_path


def test_a_run_name_is_one_plain_component():
    from cec.training.config import TrainConfig

    for name in ("/tmp/abs", "../up", ".hidden"):
        with pytest.raises(ConfigError, match="run name .* cannot be a file or folder name"):
            load_config(TrainConfig, None, ["algorithm=ippo", "env.levels=cramped_room", f"name={name}"])


def _state() -> dict[str, Any]:
    return {"w": np.ones(3, np.float32)}


def _save(path: Path) -> Path:
    return checkpoints.save(path, _state(), update=1, env_steps=2, config={}, metadata={})


def test_a_checkpoint_never_replaces_a_folder_that_is_not_one(tmp_path):
    victim = tmp_path / "notes"
    victim.mkdir()
    (victim / "precious.txt").write_text("mine")
    with pytest.raises(checkpoints.CheckpointError, match="exists and is not a checkpoint .*precious.txt"):
        _save(victim)
    assert (victim / "precious.txt").read_text() == "mine"
    (tmp_path / "file").write_text("mine")
    with pytest.raises(checkpoints.CheckpointError, match="is a file, not a checkpoint folder"):
        _save(tmp_path / "file")
    other = tmp_path / "ckpt.tmp"  # what save writes first: someone else's folder of that name is kept too
    other.mkdir()
    (other / "precious.txt").write_text("mine")
    with pytest.raises(checkpoints.CheckpointError, match="ckpt.tmp exists and is not a checkpoint"):
        _save(tmp_path / "ckpt")
    assert (other / "precious.txt").read_text() == "mine" and not (tmp_path / "ckpt").exists()
    # its own: an empty folder, a checkpoint written before, an interrupted write's leftovers
    (tmp_path / "empty").mkdir()
    _save(tmp_path / "empty")
    again = _save(tmp_path / "empty")
    assert checkpoints.read_meta(again)["update"] == 1
    (tmp_path / "cut.tmp").mkdir()
    (tmp_path / "cut.tmp" / checkpoints.STATE_FILE).write_bytes(b"half")
    assert checkpoints.read_meta(_save(tmp_path / "cut"))["update"] == 1


def _manifest(tmp_path: Path, saved_run: tuple[Path, Path, Any], name: str) -> Path:
    path = tmp_path / "shared.yaml"
    entry = {"name": name, "algorithm": "ippo", "seed": 4, "checkpoint": str(saved_run[1])}
    path.write_text(yaml.safe_dump({"policies": [entry]}))
    return path


def _victim(tmp_path: Path) -> Path:
    victim = tmp_path / "victim"
    victim.mkdir(parents=True)
    (victim / "precious.txt").write_text("mine")
    return victim


@pytest.mark.parametrize("how", ["name", "prefix"])
def test_cec_zoo_export_keeps_every_write_inside_its_folder(how, saved_run, tmp_path):
    """A shared manifest naming `../victim` (or an absolute path), or `--prefix ../`: the folder outside
    `--out` was removed and replaced by a checkpoint. Now exit 2 before anything is loaded or written."""
    victim = _victim(tmp_path)
    name = {"name": "../victim", "absolute": str(victim), "prefix": "victim"}[how]
    extra = ["--prefix", "../"] if how == "prefix" else []
    out = tmp_path / "out"
    proc = _cec("zoo", "export", str(_manifest(tmp_path, saved_run, name)), "--out", str(out), *extra)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "cannot be a file or folder name: it holds a path separator" in proc.stderr
    assert ("--prefix" if how == "prefix" else "rename the entry") in proc.stderr
    assert "Traceback" not in proc.stderr
    assert (victim / "precious.txt").read_text() == "mine" and sorted(victim.iterdir()) == [
        victim / "precious.txt"
    ]
    assert not out.exists()


def test_cec_zoo_export_refuses_to_replace_a_folder_that_is_not_a_checkpoint(saved_run, tmp_path):
    out = tmp_path / "out"
    _victim(out)  # out/victim: someone's folder where the entry `victim` would go
    proc = _cec("zoo", "export", str(_manifest(tmp_path, saved_run, "victim")), "--out", str(out))
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "victim exists and is not a checkpoint (it holds precious.txt)" in proc.stderr
    assert "nothing was written or removed" in proc.stderr
    assert (out / "victim" / "precious.txt").read_text() == "mine"
