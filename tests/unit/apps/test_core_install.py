"""The `cec` core without the platform: a machine with the core install alone (a GPU box) trains, evaluates
and reports; the services' commands say which package is missing and how to install it.

The platform's packages are made unimportable in a child process (an import hook), which is what an
install without the `services` extra looks like to the code; the package metadata is checked to match.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[3]
# Top-level modules of the `services` extra's distributions (and what they pull in that the core lacks).
PLATFORM = ("ray", "redis", "starlette", "uvicorn", "websockets", "grpc", "grpc_health", "grpc_reflection",
            "prometheus_client")  # fmt: skip
SERVICES_EXTRA = ("grpcio", "grpcio-health-checking", "grpcio-reflection", "prometheus-client", "redis",
                  "ray", "starlette", "uvicorn", "websockets")  # fmt: skip

BLOCK = f"""
import sys
class _Absent:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {PLATFORM!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name.split(".")[0])
        return None
sys.meta_path.insert(0, _Absent())
from apps.cli import main
code = main(sys.argv[1:])
leaked = sorted(m for m in sys.modules if m.split(".")[0] in {PLATFORM!r})
assert not leaked, leaked
raise SystemExit(code)
"""


def _cec_core(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", BLOCK, *args], cwd=ROOT, capture_output=True, text=True, timeout=600
    )


def _name(requirement: str) -> str:
    return requirement.split(";")[0].split("[")[0].split(">")[0].split("=")[0].split("<")[0].strip()


def test_the_platform_packages_are_an_extra_that_make_installs() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core = {_name(r) for r in project["dependencies"]}
    assert core.isdisjoint(SERVICES_EXTRA)
    assert {_name(r) for r in project["optional-dependencies"]["services"]} == set(SERVICES_EXTRA)
    assert "'.[services," in (ROOT / "Makefile").read_text()


@pytest.mark.slow
def test_the_core_trains_and_evaluates_without_the_platform(tmp_path: Path) -> None:
    config = tmp_path / "quick.yaml"
    config.write_text(
        yaml.safe_dump(
            {
                "algorithm": "ippo",
                "num_envs": 4,
                "num_steps": 8,
                "total_env_steps": 64,
                "network": "small",
                "env": {"name": "dual_destination", "levels": "fixed", "dual_destination": {"max_steps": 8}},
                "run_dir": str(tmp_path / "runs"),
                "name": "core",
            }  # fmt: skip
        )
    )
    trained = _cec_core("train", "--config", str(config), "--quiet")
    assert trained.returncode == 0, trained.stderr
    run = tmp_path / "runs" / "core"
    assert list((run / "checkpoints").glob("update_*")), trained.stderr
    zoo = tmp_path / "zoo.yaml"
    zoo.write_text(yaml.safe_dump({"policies": [{"name": "a", "checkpoint": str(run)}]}))
    results = tmp_path / "results.csv"
    scored = _cec_core(
        "eval", "--zoo", str(zoo), "--levels", "fixed", "--episodes", "1", "--out", str(results)
    )
    assert scored.returncode == 0, scored.stderr
    assert results.read_text().count("\n") > 1


def test_a_service_command_names_the_missing_package() -> None:
    up = _cec_core("up")
    assert up.returncode == 2
    assert "needs the package" in up.stderr and "pip install -e '.[services]'" in up.stderr
