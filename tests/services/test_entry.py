"""services.entry: every service's command line maps bad input to exit 2, an operational failure to exit 1
(one line on stderr, no traceback), registers under `cec` from the one list, and runs as `python -m`."""

from __future__ import annotations

import argparse
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from apps.cli import COMMANDS, build_parser
from apps.cli import main as cec_main
from cec.checkpoints import CheckpointError
from cec.config import ConfigError
from services.entry import Service, config_arguments, load_service_config

ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Toy:
    """A service config: `rate` must be positive."""

    rate: int = 1

    def __post_init__(self) -> None:
        if self.rate < 1:
            raise ConfigError(f"rate must be >= 1, got {self.rate}")


def _service(failure: BaseException | None = None) -> Service:
    def run(args: argparse.Namespace) -> int:
        config = load_service_config(Toy, args)
        if failure is not None:
            raise failure
        print(f"rate {config.rate}")
        return 0

    return Service(
        "toy", "services.toy", "a toy service", lambda p: config_arguments(p, "toy.yaml", "rate=2"), run
    )


def test_exit_statuses_and_one_line_errors(capsys, tmp_path):
    assert _service().main(["rate=3"]) == 0
    assert capsys.readouterr().out == "rate 3\n"

    assert _service().main(["rate=0"]) == 2
    err = capsys.readouterr().err
    assert err == "cec toy: config error: rate must be >= 1, got 0\n"

    assert _service().main(["--config", str(tmp_path / "none.yaml")]) == 2
    assert "none.yaml" in capsys.readouterr().err

    assert _service(CheckpointError("checksum mismatch")).main([]) == 2
    assert capsys.readouterr().err == "cec toy: error: checksum mismatch\n"

    assert _service(OSError("port 50051 in use")).main([]) == 1
    assert capsys.readouterr().err == "cec toy: error: port 50051 in use\n"


def test_a_bug_keeps_its_traceback():
    with pytest.raises(KeyError):
        _service(KeyError("bug")).main([])


def test_registered_under_cec(capsys):
    sub = argparse.ArgumentParser(prog="cec").add_subparsers(dest="command", required=True)
    _service().register(sub)
    parser = sub.choices["toy"]
    args = parser.parse_args(["rate=5"])
    assert args.func(args) == 0 and capsys.readouterr().out == "rate 5\n"


def test_one_registration_list_covers_every_service_main():
    """Every services/*/main.py is a Service and is in apps.cli.COMMANDS; every command there parses."""
    mains = sorted(p.parent.name for p in (ROOT / "services").glob("*/main.py"))
    listed = {module for module, _ in COMMANDS}
    assert mains and all(f"services.{name}.main" in listed for name in mains), mains
    commands = build_parser()._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    for module, names in COMMANDS:
        assert set(names) <= set(commands), (module, names)


def test_cec_and_python_m_agree(capsys):
    assert cec_main(["level-server", "port=-5"]) == 2
    via_cec = capsys.readouterr().err
    proc = subprocess.run(
        [sys.executable, "-m", "services.level_server", "port=-5"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2 and proc.stderr.strip().splitlines()[-1] == via_cec.strip()
    assert via_cec.startswith("cec level-server: config error: ") and "Traceback" not in proc.stderr
