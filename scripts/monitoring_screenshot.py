"""Takes the README's monitoring picture from a real run: `cec up --monitoring` (the default preset), then
Prometheus' own graph page in headless Chromium once the evaluator has scored a few checkpoints.

    python scripts/monitoring_screenshot.py --out docs/monitoring.png [--scored 4] [overrides ...]

Needs Debian's prometheus, chromium and chromium-driver packages (as the e2e tests do). Debian's
Prometheus ships the classic UI only, so the page is `/classic/graph`. Grafana cannot be installed on the
machines this project is built on; its dashboards (cluster/grafana/dashboards/) are JSON-tested instead.
Prints what it waits for; the stack is stopped (SIGTERM) however the script ends.
"""

from __future__ import annotations

import argparse
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
from pathlib import Path

from prometheus_client.parser import text_string_to_metric_families

REPO = Path(__file__).resolve().parents[1]
URL = re.compile(r"^(prometheus|evaluator metrics)\s+(http://\S+)", re.M)
PANELS = (
    ("cec_learner_env_steps_per_second", "env steps/s"),
    ("cec_evaluator_return", "the evaluator's score of each new checkpoint"),
    ("cec_learner_episode_return", "training return"),
)


def _scored(metrics_url: str) -> float:
    try:
        with urllib.request.urlopen(metrics_url, timeout=2) as r:
            text = r.read().decode()
    except OSError:
        return 0.0
    for family in text_string_to_metric_families(text):
        if family.name == "cec_evaluator_checkpoints_scored":
            return sum(s.value for s in family.samples if s.name.endswith("_total"))
    return 0.0


def graph_url(prometheus: str, minutes: int) -> str:
    query: dict[str, str] = {}
    for i, (expr, _) in enumerate(PANELS):
        query |= {f"g{i}.expr": expr, f"g{i}.tab": "0", f"g{i}.range_input": f"{minutes}m"}
    return f"{prometheus.rstrip('/')}/classic/graph?{urllib.parse.urlencode(query)}"


def screenshot(url: str, out: Path) -> None:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_path = shutil.which("chromedriver")
    if not (chromium and driver_path):
        raise SystemExit("needs headless Chromium (Debian: apt-get install chromium chromium-driver)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1280,2050"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(driver_path), options=opts)
    try:
        driver.get(url)
        time.sleep(5)  # the graphs draw after their queries return
        driver.execute_script("document.activeElement.blur(); window.scrollTo(0, 0);")  # no focused input
        time.sleep(1)
        out.parent.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(out))
    finally:
        driver.quit()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "monitoring.png")
    ap.add_argument("--scored", type=int, default=4, help="wait for this many scored checkpoints")
    ap.add_argument("--timeout-min", type=float, default=40)
    ap.add_argument("overrides", nargs="*", help="more `cec up` overrides (KEY=VALUE)")
    args = ap.parse_args()
    run_dir = Path(tempfile.mkdtemp(prefix="cec-monitoring-"))
    cmd = [
        sys.executable, "-m", "apps.cli", "up", "--monitoring",
        "level_server_port=0", "level_server_metrics_port=0", "evaluator_metrics_port=0",
        "distributed.metrics_port=0", "monitoring_config.prometheus_port=0",
        f"train.run_dir={run_dir}", "train.name=monitoring", *args.overrides,
    ]  # fmt: skip
    log_path = run_dir / "up.log"
    started = time.monotonic()
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
        try:
            urls: dict[str, str] = {}
            scored = 0.0
            while scored < args.scored:
                if proc.poll() is not None:
                    raise SystemExit(
                        f"`cec up` ended (exit {proc.returncode}):\n{log_path.read_text()[-3000:]}"
                    )
                if time.monotonic() - started > args.timeout_min * 60:
                    raise SystemExit(f"no {args.scored} scored checkpoints in {args.timeout_min} min")
                urls |= dict(URL.findall(log_path.read_text()))
                if "evaluator metrics" in urls:
                    scored = _scored(urls["evaluator metrics"])
                minutes = (time.monotonic() - started) / 60
                print(
                    f"\r{minutes:5.1f} min: {scored:.0f}/{args.scored} checkpoints scored", end="", flush=True
                )
                time.sleep(5)
            print()
            minutes = int((time.monotonic() - started) / 60) + 1
            url = graph_url(urls["prometheus"], minutes)
            screenshot(url, args.out)
            print(f"wrote {args.out} from {url}\n(run: {run_dir}; `cec up` log: {log_path})")
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                proc.wait(300)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
