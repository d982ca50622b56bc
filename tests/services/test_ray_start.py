"""Ray start-up failures in this project's words (issue 63, item 8): a Ray head that exits (Ray timing out
in its own start-up on a heavily loaded machine) or is not ready in time, and a driver that cannot reach
Ray, are reported naming the setting to raise, not with Ray's exception text. The head is a stand-in
process (`start_ray_head` runs whatever follows `python -u`), so no Ray starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from services.learner.driver import RAY_WAIT_VARIABLE, RayStartError, connect_ray
from services.service_process import start_ray_head

#: What Ray's head prints when its raylet does not register in time (ray/_private/node.py).
RAY_TIMED_OUT = (
    "Exception: The current node timed out during startup. This could happen because some of the raylet "
    "failed to startup or the GCS has become overloaded."
)


def test_a_ray_head_that_times_out_in_its_start_up_names_start_timeout_s(tmp_path: Path) -> None:
    log = tmp_path / "ray.log"
    fake = f"import sys; print('Traceback (most recent call last):'); print({RAY_TIMED_OUT!r}); sys.exit(1)"
    with pytest.raises(RayStartError) as caught:
        start_ray_head(["-c", fake], log, timeout=60)
    message = str(caught.value)
    assert message.startswith("Ray's head did not start: it exited (its last line: Exception: The current")
    assert "raise start_timeout_s (now 60 s; `cec up start_timeout_s=600 ...`)" in message
    assert "distributed.ray_address=HOST:PORT" in message and str(log) in message
    assert "Traceback" not in message


def test_a_ray_head_not_ready_in_time_names_start_timeout_s(tmp_path: Path) -> None:
    slow = "import time; print('Usage stats collection is disabled.', flush=True); time.sleep(60)"
    with pytest.raises(RayStartError) as caught:
        start_ray_head(["-c", slow], tmp_path / "ray.log", timeout=0.5)
    message = str(caught.value)
    assert "it was not ready within start_timeout_s = 0.5 s" in message
    assert "`cec up start_timeout_s=600 ...`" in message


def test_a_driver_that_cannot_reach_ray_names_rays_wait(monkeypatch: pytest.MonkeyPatch) -> None:
    import ray

    def timed_out(**_: object) -> None:  # what ray.init raises when the head answers too late
        raise TimeoutError(
            "Timed out after 60 seconds while waiting for node to startup. Did not find socket name "
            "/tmp/ray/session_x/sockets/plasma_store in the list of object store socket names."
        )

    monkeypatch.setattr(ray, "init", timed_out)
    with pytest.raises(RayStartError) as caught:
        connect_ray("127.0.0.1:6379")
    message = str(caught.value)
    assert message.startswith("cannot connect to Ray at 127.0.0.1:6379 (TimeoutError: Timed out after 60")
    assert f"{RAY_WAIT_VARIABLE}=300" in message and "ray status --address 127.0.0.1:6379" in message


def test_cec_up_names_start_timeout_s_when_rays_head_is_not_ready_in_time(tmp_path: Path) -> None:
    """Through `cec up`: a head not ready within start_timeout_s (0.3 s: Ray's import alone takes longer)
    is one config error naming the setting to raise, not Ray's exception text."""
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[2]
    # the smoke preset's fixed kitchens: no level server starts before Ray (it has the same time-out)
    cmd = [sys.executable, "-m", "apps.cli", "up", "--config", "configs/up/smoke.yaml"]
    cmd += [f"train.run_dir={tmp_path}", "train.name=up"]
    cmd += ["evaluator=false", "start_timeout_s=0.3"]
    proc = subprocess.run(cmd, cwd=repo, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "config error: Ray's head did not start: it was not ready within start_timeout_s = 0.3 s" in (
        proc.stderr
    ), proc.stderr[-3000:]
    assert "`cec up start_timeout_s=600 ...`" in proc.stderr and "distributed.ray_address" in proc.stderr
    assert "Traceback" not in proc.stderr
