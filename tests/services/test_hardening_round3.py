"""Third hardening round (issue 63) for `cec up`: the live-run guard fails closed (a child record it cannot
read refuses the start, and its advice names only a `cec up`), and every port is checked for range and
for clashes among the stack's own services before anything starts."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from services.processes import RECORD_MAX_BYTES, ChildRecord, free_port

REPO = Path(__file__).resolve().parents[2]


def _up(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "apps.cli", "up", *args, f"train.run_dir={tmp_path}", "train.name=up"]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)


def _record(tmp_path: Path) -> Path:
    path = tmp_path / "up" / "logs" / "children.json"
    path.parent.mkdir(parents=True)
    return path


LIVE = {"owner": 12, "owner_cmd": "python\0-m\0apps.cli\0up\0", "children": []}
MALFORMED = {
    "truncated": (
        '{"owner": 4242, "owner_cmd": "python\\u0000cec\\u0000up", "children": [',
        "not valid JSON",
    ),
    "nan": ('{"owner": NaN, "children": []}', "NaN is not a JSON number"),
    "owner_not_an_int": (json.dumps({**LIVE, "owner": "12x"}), "owner must be a process id"),
    "owner_a_string_number": (json.dumps({**LIVE, "owner": "12"}), "owner must be a process id"),
    "children_not_a_list": (json.dumps({**LIVE, "children": {"pid": 5}}), "children must be a list"),
    "child_without_pid": (json.dumps({**LIVE, "children": [{"name": "x"}]}), r"children\[0\] must be"),
    "not_an_object": ("[1, 2]", "not an object"),
    "over_the_cap": (" " * (RECORD_MAX_BYTES + 1) + "{}", "larger than 1,048,576 bytes"),
}


@pytest.mark.parametrize("kind", sorted(MALFORMED))
def test_an_unreadable_child_record_refuses_the_start_naming_it_and_the_safe_way_to_clear_it(kind, tmp_path):
    text, cause = MALFORMED[kind]
    path = _record(tmp_path)
    path.write_text(text)
    with pytest.raises(ValueError, match=cause) as info:
        ChildRecord(path).check()
    message = str(info.value)
    assert str(path) in message and "nothing was started" in message
    assert f"delete {path}" in message and "If no `cec up` of this run still runs" in message
    assert ChildRecord(path).recorded() is None, "`cec status` shows no services, without an error"


def test_cec_up_resume_refuses_a_truncated_child_record_before_starting_anything(tmp_path):
    """A truncated `logs/children.json` let a second `cec up --resume` start beside the live one."""
    path = _record(tmp_path)
    path.write_text(MALFORMED["truncated"][0])
    proc = _up(tmp_path, "--resume")
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert f"child record {str(path)!r} is not valid JSON" in proc.stderr and f"delete {path}" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "up" / "redis").exists(), "nothing was started"


def test_the_advice_never_names_a_process_that_is_not_a_cec_up(tmp_path):
    """A record from before the owner's command line was kept, or one naming a reused pid (here pid 1):
    not a live `cec up`, so no `kill -INT 1`."""
    path = _record(tmp_path)
    for record in (
        {"owner": 1, "children": []},  # the old format: no owner command line
        {
            "owner": 1,
            "owner_cmd": Path("/proc/1/cmdline").read_bytes().decode(errors="replace"),
            "children": [],
        },
        {"owner": 1, "owner_cmd": "python\0cec\0up\0", "children": []},  # pid 1 runs something else
    ):
        path.write_text(json.dumps(record))
        ChildRecord(path).check()  # no live run, no leftovers: the start goes on


@pytest.mark.parametrize("key", ["level_server_port", "level_server_metrics_port", "evaluator_metrics_port"])
def test_a_port_out_of_range_is_a_config_error_before_anything_starts(key, tmp_path):
    """`cec up level_server_port=70000` ended in an OverflowError traceback."""
    proc = _up(tmp_path, f"{key}=70000")
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert f"config error: {key} must be a TCP port in 1..65535, 0 (a free one)" in proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "up").exists()


@pytest.mark.parametrize(
    ("first", "second"),
    [
        (
            ("level_server_metrics_port", "the level server's metrics"),
            ("evaluator_metrics_port", "the evaluator's metrics"),
        ),
        (
            ("level_server_port", "the level server's gRPC"),
            ("monitoring_config.prometheus_port", "Prometheus"),
        ),
    ],
)
def test_two_of_the_stacks_services_on_one_port_are_refused_before_anything_starts(first, second, tmp_path):
    """Both passed the check that the port is free, and the second failed two minutes later, after Redis
    and the level server had started."""
    port = free_port()
    proc = _up(tmp_path, "--monitoring", f"{first[0]}={port}", f"{second[0]}={port}")
    assert proc.returncode == 2, proc.stderr[-2000:]
    both = f"port {port} is given to both {first[1]} ({first[0]}) and {second[1]} ({second[0]})"
    assert both in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "up" / "redis").exists(), "nothing was started"


def test_cec_level_server_refuses_one_port_for_its_grpc_and_its_metrics_before_serving(tmp_path):
    """Both were checked for range only: the metrics server started on the port, then gRPC failed to bind
    it with a guess that another process held it."""
    port = free_port()
    cmd = [sys.executable, "-m", "apps.cli", "level-server", f"port={port}", f"metrics_port={port}"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert (
        f"config error: port {port} is given to both the level server's gRPC (port) and its metrics "
        "(metrics_port)" in proc.stderr
    ), proc.stderr[-2000:]
    assert "metrics at" not in proc.stderr and "Traceback" not in proc.stderr


def test_cec_up_refuses_a_non_ascii_token_in_the_environment_before_starting_anything(tmp_path, monkeypatch):
    """`cec up` with a level server started Redis first; the level server then refused the variable."""
    monkeypatch.setenv("CEC_LEVEL_SERVER_TOKEN", "schl\u00fcssel")
    proc = _up(tmp_path, "train.algorithm=cec", "train.env.levels=generator")
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "the CEC_LEVEL_SERVER_TOKEN environment variable must be printable ASCII" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "up" / "redis").exists(), "nothing was started"


def test_a_non_ascii_token_in_the_environment_is_refused_like_auth_token(tmp_path, monkeypatch):
    """`auth_token=` was checked for printable ASCII, `CEC_LEVEL_SERVER_TOKEN` was not: the server started
    with a token no client can send."""
    from services.level_server.client import LevelClient

    monkeypatch.setenv("CEC_LEVEL_SERVER_TOKEN", "schlüssel")
    cmd = [sys.executable, "-m", "apps.cli", "level-server", "port=0", "metrics_port=-1"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "the CEC_LEVEL_SERVER_TOKEN environment variable must be printable ASCII" in proc.stderr
    with pytest.raises(
        ValueError, match="CEC_LEVEL_SERVER_TOKEN environment variable must be printable ASCII"
    ):
        LevelClient("127.0.0.1:1")  # a client with it: refused before any call, naming the variable
