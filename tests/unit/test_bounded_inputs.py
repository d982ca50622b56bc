"""Files taken from a user or a run folder are read in bounded memory and time, and every bad one ends in a
clear error naming the file and the cause (issue 44, second hardening round): the one reader
(`cec.config.read_user_*`), zoo manifests, checkpoint metadata, run folders `cec train` cannot write,
human data (`cec humans`), level-server PEM files and tokens sent in plaintext, and a zoo whose entries
share no level of the evaluation (`cec eval`)."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import subprocess
import sys
import zipfile
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cec import checkpoints
from cec.agents import zoo
from cec.config import ConfigError, read_user_bytes, read_user_json, read_user_yaml
from cec.humans import data as human_data
from cec.humans.data import HumanDataError, Steps, load_steps, save_steps

REPO = Path(__file__).resolve().parents[2]


def _cec(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "apps.cli", *args]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=timeout)


def _zero(tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    path.symlink_to("/dev/zero")  # a file that never ends: read whole, it took memory until MemoryError
    return path


def _fifo(tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    os.mkfifo(path)  # reading it blocks until a writer comes: for good
    return path


# ---- the reader -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("make", [_zero, _fifo])
@pytest.mark.parametrize("reader", [read_user_bytes, read_user_json, read_user_yaml])
def test_the_reader_refuses_devices_and_fifos_at_once(tmp_path, make, reader):
    path = make(tmp_path, "x")
    with pytest.raises(ConfigError, match="is not a regular file") as info:
        reader(path, "test file", 1024, "SETTING")
    assert str(path) in str(info.value)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(content=st.binary(max_size=300), cap=st.integers(0, 256))
def test_the_reader_returns_a_file_within_its_cap_or_names_the_cap_and_its_setting(tmp_path, content, cap):
    path = tmp_path / "file.bin"
    path.write_bytes(content)
    if len(content) <= cap:
        assert read_user_bytes(path, "test file", cap, "x.MAX") == content
    else:
        with pytest.raises(ConfigError) as info:
            read_user_bytes(path, "test file", cap, "x.MAX")
        assert f"larger than {cap:,} bytes" in str(info.value) and "(x.MAX)" in str(info.value)
        assert str(path) in str(info.value)


def test_json_and_yaml_readers_refuse_deep_nesting_and_nan_naming_the_file(tmp_path):
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ConfigError, match="nests too deeply") as info:
        read_user_json(deep, "test file", 1 << 20, "S")
    assert str(deep) in str(info.value)
    with pytest.raises(ConfigError, match="nests too deeply"):
        read_user_yaml(deep, "test file", 1 << 20, "S")
    nan = tmp_path / "nan.json"
    nan.write_text('{"a": NaN}')
    with pytest.raises(ConfigError, match="NaN is not a JSON number"):
        read_user_json(nan, "test file", 1024, "S")


# ---- zoo manifests ----------------------------------------------------------------------------------------


def test_a_zoo_manifest_is_read_bounded(tmp_path):
    for path, message in [
        (_zero(tmp_path, "zero.yaml"), "is not a regular file"),
        (_fifo(tmp_path, "fifo.json"), "is not a regular file"),
        (tmp_path, "zoo.yaml' does not exist"),  # a folder stands for its manifest (a bundle)
    ]:
        with pytest.raises(ConfigError, match=message) as info:
            zoo.load_zoo(path)
        assert str(path) in str(info.value)
    big = tmp_path / "big.yaml"
    big.write_text("# pad\n" * (zoo.ZOO_MAX_BYTES // 6 + 1))
    with pytest.raises(ConfigError, match="ZOO_MAX_BYTES"):
        zoo.load_zoo(big)
    deep = tmp_path / "deep.yaml"
    deep.write_text("policies: " + "[" * 20_000 + "]" * 20_000)
    with pytest.raises(ConfigError, match="nests too deeply"):
        zoo.load_zoo(deep)


def test_a_zoo_of_10000_entries_is_refused_at_once_through_cec_eval(tmp_path):
    manifest = tmp_path / "zoo.json"
    entries = [{"name": f"p{i}", "checkpoint": "cec758m-s200"} for i in range(10_000)]
    manifest.write_text(json.dumps({"policies": entries}))
    with pytest.raises(ConfigError, match="ZOO_MAX_ENTRIES"):
        zoo.load_zoo(manifest)
    proc = _cec("eval", "--zoo", str(manifest), "--out", str(tmp_path / "r.csv"))
    assert proc.returncode == 2, proc.stderr
    assert "10,000 policies, more than the 512" in proc.stderr and "Traceback" not in proc.stderr
    assert zoo.parse_zoo([{"name": f"p{i}", "scripted": "dd_oracle"} for i in range(zoo.ZOO_MAX_ENTRIES)])


def test_zoo_entries_that_share_no_level_of_the_evaluation_are_a_clear_error(tmp_path):
    manifest = tmp_path / "zoo.yaml"
    manifest.write_text("policies:\n- {name: a, scripted: dd_oracle, levels: [nope]}\n")
    proc = _cec("eval", "--zoo", str(manifest), "--episodes", "1", "--out", str(tmp_path / "r.csv"))
    assert proc.returncode == 2, proc.stderr
    assert "no game to play" in proc.stderr and "a plays only ['nope']" in proc.stderr
    assert "Traceback" not in proc.stderr  # was: TypeError from jax.tree.map over no policy


# ---- checkpoints and run folders --------------------------------------------------------------------------


def test_checkpoint_metadata_is_read_bounded(tmp_path):
    ckpt = tmp_path / "update_000000001"
    ckpt.mkdir()
    _zero(ckpt, checkpoints.META_FILE)
    with pytest.raises(checkpoints.CorruptCheckpointError, match="is not a regular file"):
        checkpoints.read_meta(ckpt)
    (ckpt / checkpoints.META_FILE).unlink()
    (ckpt / checkpoints.META_FILE).write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(checkpoints.CorruptCheckpointError, match="nested too deeply"):
        checkpoints.read_meta(ckpt)


def test_cec_train_into_a_run_dir_it_cannot_create_exits_2_naming_it(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(ConfigError, match="cannot be created or written"):
        checkpoints.RunLock(blocker / "run").acquire()
    proc = _cec("train", "--config", "configs/train/cramped_room_ci.yaml", f"run_dir={blocker}/sub")
    assert proc.returncode == 2, proc.stderr
    assert f"run directory '{blocker}/sub/" in proc.stderr and "give run_dir=" in proc.stderr
    assert "Traceback" not in proc.stderr


# ---- human data -------------------------------------------------------------------------------------------


def _steps(n: int = 4) -> Steps:
    """`n` rows of zeros: valid values for every array of a split."""
    arrays = {}
    for name, (dtype, shape, _lo, _hi) in human_data._SPEC.items():
        arrays[name] = np.zeros((n, *shape), dtype)
    return Steps(**arrays)


def _write_split(folder: Path, arrays: dict[str, np.ndarray] | None = None, raw: bytes | None = None) -> Path:
    """A valid imported folder whose train.npz is replaced by `arrays` or `raw` bytes, meta.json's SHA-256
    recomputed (as an adversary would)."""
    save_steps({"train": _steps()}, folder, source={})
    path = folder / "train.npz"
    if arrays is not None:
        np.savez_compressed(path, **arrays)
    if raw is not None:
        path.write_bytes(raw)
    meta = json.loads((folder / "meta.json").read_text())
    meta["splits"]["train"]["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    (folder / "meta.json").write_text(json.dumps(meta))
    return path


def test_human_data_round_trips(tmp_path):
    save_steps({"train": _steps()}, tmp_path, source={})
    assert len(load_steps(tmp_path, "train")) == 4


@pytest.mark.parametrize(
    "meta",
    [
        {"format": "cec-humans/1", "splits": "train"},
        {"format": "cec-humans/1", "splits": {"train": []}},
        {"format": "cec-humans/1", "splits": {"train": {}}},
        {"format": "cec-humans/1", "splits": None},
        ["cec-humans/1"],
    ],
)
def test_malformed_meta_json_is_refused_naming_it(tmp_path, meta):
    save_steps({"train": _steps()}, tmp_path, source={})
    (tmp_path / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(HumanDataError, match="meta.json") as info:
        load_steps(tmp_path, "train")
    assert "cec humans import" in str(info.value)


def test_meta_json_that_never_ends_is_refused(tmp_path):
    save_steps({"train": _steps()}, tmp_path, source={})
    (tmp_path / "meta.json").unlink()
    _zero(tmp_path, "meta.json")
    with pytest.raises(HumanDataError, match="meta.json' is not a regular file"):
        load_steps(tmp_path, "train")


def test_nan_rewards_are_refused(tmp_path):
    arrays = {f.name: getattr(_steps(), f.name) for f in fields(Steps)}
    arrays["reward"] = np.array([0.0, np.nan, 0.0, 0.0], np.float32)
    _write_split(tmp_path, arrays)
    with pytest.raises(HumanDataError, match="array reward has 1 NaN or infinite value"):
        load_steps(tmp_path, "train")
    with pytest.raises(HumanDataError, match="NaN"):
        save_steps({"train": Steps(**arrays)}, tmp_path / "out", source={})


def test_an_npz_that_is_not_a_zip_exits_2_naming_it_without_pickle_advice(tmp_path):
    path = _write_split(tmp_path, raw=b"\x80\x04not a zip at all" * 100)
    with pytest.raises(HumanDataError, match="is not a .npz archive"):
        load_steps(tmp_path, "train")
    proc = _cec("humans", "replay", "--data", str(tmp_path))
    assert proc.returncode == 2, proc.stderr
    assert str(path) in proc.stderr and "pickle" not in proc.stderr and "Traceback" not in proc.stderr


def _bomb(path: Path, name: str, shape: tuple[int, ...], dtype: str, data_bytes: int, pad: bool) -> None:
    """A .npz whose `name` array's header declares `shape`; its data are `data_bytes` zeros, deflated."""
    arrays = {f.name: getattr(_steps(), f.name) for f in fields(Steps)}
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for other, array in arrays.items():
            if other == name:
                continue
            with archive.open(f"{other}.npy", "w") as member:
                np.lib.format.write_array(member, array)
        with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
            header = {"descr": dtype, "fortran_order": False, "shape": shape}
            np.lib.format.write_array_header_1_0(member, header)
            chunk = bytes(1 << 20)
            left = data_bytes
            while pad and left > 0:
                member.write(chunk[: min(left, len(chunk))])
                left -= len(chunk)


def test_an_npz_inflating_past_the_cap_is_refused_before_inflating(tmp_path, monkeypatch):
    monkeypatch.setattr(human_data, "SPLIT_MAX_BYTES", 1 << 20)
    path = _write_split(tmp_path)
    _bomb(path, "reward", (800_000,), "<f4", 3_200_000, pad=True)  # 3.2 MB of zeros in ~3 kB
    _write_split(tmp_path, raw=path.read_bytes())
    assert path.stat().st_size < 50_000
    with pytest.raises(HumanDataError, match="would take more than 1,048,576 bytes inflated") as info:
        load_steps(tmp_path, "train")
    assert "SPLIT_MAX_BYTES" in str(info.value)


def test_an_npz_whose_header_declares_more_than_its_member_holds_is_refused(tmp_path):
    path = _write_split(tmp_path)
    _bomb(path, "reward", (4_000_000_000,), "<f4", 0, pad=False)  # 16 GB declared, nothing stored
    _write_split(tmp_path, raw=path.read_bytes())
    with pytest.raises(HumanDataError, match="declares"):
        load_steps(tmp_path, "train")


def test_an_npz_with_another_dtype_or_extra_arrays_is_refused(tmp_path):
    arrays = {f.name: getattr(_steps(), f.name) for f in fields(Steps)}
    _write_split(tmp_path, {**arrays, "reward": arrays["reward"].astype(object)})
    with pytest.raises(HumanDataError, match="array reward is object"):
        load_steps(tmp_path, "train")
    _write_split(tmp_path, {**arrays, "extra": np.zeros(3)})
    with pytest.raises(HumanDataError, match="unexpected \\['extra.npy'\\]"):
        load_steps(tmp_path, "train")


# ---- level server: PEM files and tokens -------------------------------------------------------------------


@pytest.mark.parametrize("make", [_zero, _fifo])
def test_pem_files_are_read_bounded_by_cec_level_server_and_cec_levels_stream(tmp_path, make):
    pem = make(tmp_path, "cert.pem")
    proc = _cec("level-server", f"tls_cert={pem}", f"tls_key={pem}", timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert f"tls_cert file '{pem}' is not a regular file" in proc.stderr and "Traceback" not in proc.stderr
    proc = _cec("levels", "stream", "--root-cert", str(pem), "--n", "1", timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert f"root certificate file '{pem}' is not a regular file" in proc.stderr


def test_a_pem_file_over_its_cap_names_the_setting(tmp_path):
    from services.level_server import config as server_config

    big = tmp_path / "big.pem"
    big.write_bytes(b"-----BEGIN CERTIFICATE-----\n" + b"A" * server_config.PEM_MAX_BYTES)
    with pytest.raises(ConfigError, match="services.level_server.config.PEM_MAX_BYTES"):
        server_config.read_pem(str(big), "tls_cert")


@pytest.mark.parametrize(
    ("address", "warned"),
    [
        ("10.1.2.3:50051", True),
        ("levels.example.org:50051", True),
        ("[2001:db8::1]:50051", True),
        ("127.0.0.1:50051", False),
        ("localhost:50051", False),
        ("[::1]:50051", False),
        ("dns:///localhost:50051", False),
    ],
)
def test_a_token_sent_in_plaintext_beyond_loopback_is_warned_about(caplog, address, warned):
    from services.level_server.client import LevelClient

    with caplog.at_level(logging.WARNING, logger="cec.level_client"):
        LevelClient(address, token="secret-token").close()
        LevelClient(address).close()  # no token: nothing to leak
    messages = [r.getMessage() for r in caplog.records]
    assert len(messages) == int(warned), messages
    if warned:
        assert address in messages[0] and "plaintext" in messages[0] and "secret-token" not in messages[0]
