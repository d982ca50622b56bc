"""Third hardening round (issue 63) for the library and the `cec` commands that need no service: names
become paths only through `cec.paths` (a shared zoo manifest naming `../victim` removed that folder), a
checkpoint never replaces a folder that is not one, result tables are read through one bounded
decompressing reader with strict rows, and overrides are bounded in depth like files."""

from __future__ import annotations

import bz2
import gzip
import os
import subprocess
import sys
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from cec import checkpoints
from cec.config import ConfigError, load_config
from cec.evaluation import results
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


@pytest.mark.parametrize("how", ["name", "absolute", "prefix"])
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


# ---- result tables: one bounded decompressing reader, strict rows ----------------------------------------

HEADER = ",".join(results.COLUMNS) + "\n"


def _row(episode: int = 0, ret: str = "20", seat: str = "0", policy: str = "cec0") -> str:
    return (
        f"{policy},cec,0,cec1,cec,1,cramped_room,{seat},{episode},{ret},1,0,3.5,overcooked,400,sampled,ok,\n"
    )


def test_a_bz2_bomb_of_valid_rows_is_refused_at_the_cap_without_reading_it_all(tmp_path, monkeypatch, capsys):
    """A few KB that expand to 64 MB of valid rows (the probe's 427 KB expanded to 1.5 GB and took `cec
    report` to a MemoryError): refused once the decompressed bytes pass the cap, which the error names."""
    from apps.cli import main

    rows = "".join(_row(i % 1000) for i in range(10_000))  # ~0.8 MB of rows, compressed once
    stream = bz2.compress((HEADER + rows).encode())
    more = bz2.compress(rows.encode())
    bomb = tmp_path / "results.csv.bz2"
    bomb.write_bytes(stream + more * 80)  # bzip2 streams one after another: one file, 64 MB of rows
    assert bomb.stat().st_size < 400_000
    monkeypatch.setattr(results, "RESULTS_MAX_BYTES", 1 << 20, raising=False)
    assert main(["report", str(tmp_path / "none.csv")]) == 2  # every module imported before memory is traced
    tracemalloc.start()
    try:
        status = main(["report", str(bomb), "--out", str(tmp_path / "report")])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    err = capsys.readouterr().err
    assert status == 2, err
    assert f"{str(bomb)!r} holds more than 1,048,576 bytes decompressed" in err
    assert "cec.evaluation.results.RESULTS_MAX_BYTES" in err and "Traceback" not in err
    assert peak < 20 << 20, f"{peak:,} bytes traced: the bomb was read past its cap"


def test_a_table_of_more_rows_than_the_cap_is_refused_naming_the_setting(tmp_path, monkeypatch):
    path = tmp_path / "r.csv"
    path.write_text(HEADER + "".join(_row(i) for i in range(11)))
    monkeypatch.setattr(results, "RESULTS_MAX_ROWS", 10, raising=False)
    with pytest.raises(
        results.ResultsError, match=r"more than 10 rows .*\(cec.evaluation.results.RESULTS_MAX_ROWS\)"
    ):
        results.read_csv(path)


@pytest.mark.parametrize(
    ("row", "cause"),
    [
        (_row(ret="inf"), "return must be a finite number, got 'inf'"),
        (_row(ret="-Infinity"), "return must be a finite number"),
        (_row(ret="nan"), "return must be a finite number"),
        (_row(seat="7"), "seat must be 0 or 1"),
        (_row(episode=-1), "episode must be >= 0, got -1"),
        ("cec0,cec,0,cec1\n", "the row has 4 fields, a results file 18"),
    ],
)
def test_a_row_that_is_no_played_episode_is_refused_with_its_file_and_line(row, cause, tmp_path):
    path = tmp_path / "r.csv"
    path.write_text(HEADER + _row() + row)
    with pytest.raises(results.ResultsError, match=cause) as info:
        results.read_csv(path)
    assert str(info.value).startswith(f"{path}, line 3: ")


def test_cec_report_names_the_file_and_line_of_a_field_over_the_csv_limit(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text(HEADER + _row() + _row(policy="x" * 200_000))
    proc = _cec("report", str(path), "--out", str(tmp_path / "report"))
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert f"{path}, line 3: field larger than field limit" in proc.stderr and "Traceback" not in proc.stderr


def test_cec_report_refuses_compressed_bytes_under_a_plain_name_naming_the_file(tmp_path):
    path = tmp_path / "results.csv"
    path.write_bytes(gzip.compress((HEADER + _row()).encode()))
    proc = _cec("report", str(path), "--out", str(tmp_path / "report"))
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert f"{str(path)!r} holds gz-compressed bytes but its name does not end .gz" in proc.stderr
    assert "rename it results.csv.gz" in proc.stderr and "Traceback" not in proc.stderr


def _peak_rss_mb(*args: str, env: dict[str, str] | None = None) -> tuple[float, str]:
    """(peak RSS in MB, stderr) of `cec ARGS` run as the only child of a fresh Python."""
    probe = (
        "import resource, subprocess, sys\n"
        f"p = subprocess.run([sys.executable, '-m', 'apps.cli', *{list(args)!r}], capture_output=True, "
        "text=True)\n"
        "sys.stderr.write(p.stderr[-3000:])\n"
        "print(p.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", probe], cwd=REPO, capture_output=True, text=True, timeout=900, env=env
    )
    code, kb = proc.stdout.split()
    return int(kb) / 1024, f"exit {code}: {proc.stderr}"


def _bomb_row(i: int, distinct: bool) -> str:
    if distinct:  # every name its own: a policy, an algorithm and a level per row
        outcomes = f"{i}.25,{i % 7},{i % 3},{i}.5"
        return f"p{i},a{i},{i},q{i},b{i},{i},lv{i},{i % 2},{i},{outcomes},env{i},400,s{i},ok,\n"
    a, b, seeds = i % 8, i // 64 % 8, (i // 8 % 8, i // 512 % 8)  # 64 policies, 100 levels
    return (
        f"p{a}_{seeds[0]},a{a},{seeds[0]},p{b}_{seeds[1]},a{b},{seeds[1]},lv{i % 100},{i % 2},{i},{i}.25,"
        f"{i % 7},{i % 3},{i}.5,overcooked,400,s{i},ok,\n"
    )


@pytest.fixture(scope="module")
def small_report_rss_mb(tmp_path_factory: pytest.TempPathFactory) -> float:
    """Peak RSS in MB of `cec report` on a four-row table (what the bombs' peaks are measured against):
    measured once for both bombs, a fresh Python and its imports being most of a `cec report`'s time."""
    tmp = tmp_path_factory.mktemp("small_report")
    small = tmp / "small.csv"
    small.write_text(HEADER + "".join(_row(i) for i in range(4)))
    base, err = _peak_rss_mb("report", str(small), "--out", str(tmp / "small_report"))
    assert err.startswith("exit 0"), err
    return base


@pytest.mark.slow
@pytest.mark.parametrize(
    ("kind", "rows", "message"),
    [
        ("distinct", 1_100_000, "more than 24 algorithms with the rows read before it"),
        ("rows", 1_020_000, "holds more than 1,000,000 rows"),
    ],
)
def test_cec_report_of_a_bz2_bomb_stays_within_500_mb_of_its_start(
    kind, rows, message, small_report_rss_mb, tmp_path
):
    """A few MB of bzip2 that expand to a million valid rows: `distinct`, each with its own names, took
    `cec report` 1.07 GB past its start (Python lists of objects, each name a string) before the row cap;
    `rows`, past the row cap among 64 policies. Now columns of 8 bytes a value, caps on rows, policies,
    algorithms and levels, refused at the cap the error names with the variable that raises it."""
    bomb = tmp_path / "results.csv.bz2"
    compressor = bz2.BZ2Compressor(1)
    with bomb.open("wb") as f:
        f.write(compressor.compress(HEADER.encode()))
        for start in range(0, rows, 50_000):
            chunk = "".join(_bomb_row(i, kind == "distinct") for i in range(start, start + 50_000))
            f.write(compressor.compress(chunk.encode()))
        f.write(compressor.flush())
    base = small_report_rss_mb
    peak, err = _peak_rss_mb("report", str(bomb), "--out", str(tmp_path / "report"))
    assert err.startswith("exit 2"), err
    assert peak - base < 500, f"cec report took {peak:.0f} MB, {peak - base:.0f} MB past a small table's"
    assert message in err and "=N in the environment" in err and "Traceback" not in err, err


@pytest.mark.parametrize(
    ("variable", "value", "rows", "message"),
    [
        ("CEC_RESULTS_MAX_ROWS", "3", [_row(i) for i in range(4)], "holds more than 3 rows"),
        ("CEC_RESULTS_MAX_BYTES", "500", [_row(i) for i in range(8)], "holds more than 500 bytes"),
        (
            "CEC_RESULTS_MAX_POLICIES",
            "2",
            [_row(), _row(policy="cec2").replace(",cec,0,", ",cec,2,", 1)],
            "more than 2 policies ((algorithm, seed) pairs)",
        ),
    ],
)
def test_cec_report_names_the_cap_a_table_passes_and_its_variable_raises_it(
    variable, value, rows, message, tmp_path, monkeypatch
):
    """The caps were module constants a user could not raise; the error named only the constant."""
    path = tmp_path / "r.csv"
    path.write_text(HEADER + "".join(rows))
    env = {**os.environ, variable: value}
    proc = subprocess.run(
        [sys.executable, "-m", "apps.cli", "report", str(path), "--out", str(tmp_path / "report")],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=180,
        env=env,
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert message in proc.stderr and f"{variable}=N in the environment" in proc.stderr, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    monkeypatch.setenv(variable, "10_000")
    assert len(results.read_csv(path)) == len(rows)  # raised: read


def test_a_metrics_table_csv_cannot_read_is_named_with_its_file_and_line(tmp_path):
    from cec.evaluation.curves import read_metrics_csv

    (tmp_path / "metrics.csv").write_text("update,seed,mean_return\n1,0,2.5\n2,0," + "9" * 200_000 + "\n")
    with pytest.raises(results.ResultsError, match=r"metrics.csv, line 3: field larger than field limit"):
        read_metrics_csv(tmp_path)
    (tmp_path / "metrics.csv").write_text("update,seed\n1,0,7\n")
    with pytest.raises(results.ResultsError, match="line 2: the row has more fields than the header"):
        read_metrics_csv(tmp_path)


# ---- overrides are bounded in depth like files ----------------------------------------------------------


def test_a_deeply_nested_override_is_a_config_error_not_a_recursion_error(tmp_path):
    deep = "[" * 10_000 + "]" * 10_000
    proc = _cec(
        "train", "--config", "configs/train/cramped_room_ci.yaml", f"run_dir={tmp_path}", f"seed={deep}"
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "config error: override seed=...: the value nests too deeply to be read" in proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr) < 2000
