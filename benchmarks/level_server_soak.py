"""A bounded soak of the level server's request limits over loopback (issue 23): concurrent large and
hostile `ValidateLevel` / `ReportScores` calls while a normal client keeps asking for levels.

    python benchmarks/level_server_soak.py                        # ~1.5 minutes on 2 CPU cores
    python benchmarks/level_server_soak.py --seconds 20 --attackers 4 --set max_concurrent_validations=2

The server runs as its own process (`python -m services.level_server`, default limits, the curriculum on so
that `ReportScores` is live; `--set KEY=VALUE` overrides), so its RSS is read from /proc apart from the
clients'. Attackers are threads, each with its own connection, sending in a loop, round robin:

- a 4 MiB ASCII kitchen (over `max_message_bytes`: refused by gRPC before the server parses anything),
- a 1 MiB - 1 KiB one (within `max_message_bytes`, over ValidateLevel's own bound: refused unparsed),
- a 5,000-character one (within ValidateLevel's bound, over `max_ascii_bytes`: refused before parsing),
- a real kitchen (validated: the work a legitimate client asks for),
- scores for the whole held-out set and for an unsolvable kitchen (a curriculum-poisoning attempt).

A normal client meanwhile calls `GetLevels(64)` (fresh levels) every `--interval` seconds and times each
call. Phases: warm-up; `--baseline` seconds of the normal client alone; `--seconds` of attack; then
`--settle` seconds of quiet before the last RSS reading and a second quiet latency window. The server's RSS
is sampled every 0.5 s. Targets: GetLevels p99 < 100 ms under attack; RSS after the attack at most 10% above
its start; no INTERNAL or UNKNOWN answer; no poisoning attempt accepted. Exit status 1 if one is missed.
Answers RESOURCE_EXHAUSTED to real kitchens and poisoning attempts are the validation pool being full
(`max_concurrent_validations`), as designed.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import grpc
import numpy as np

from cec.levels import stack_levels, to_ascii
from cec.levels.ascii import from_ascii
from cec.levels.heldout import heldout_levels
from cec.levels.v1 import level_service_pb2 as pb
from cec.levels.wire import encode
from services.level_server.client import LevelClient
from services.level_server.server import SERVICE_NAME

try:  # run as a script (benchmarks/ on sys.path) or as a module
    from env_throughput import git_rev, machine  # type: ignore[import-not-found]
except ImportError:  # pragma: no cover
    from benchmarks.env_throughput import git_rev, machine

ROOT = Path(__file__).resolve().parents[1]
PAGE = os.sysconf("SC_PAGE_SIZE")
UNSOLVABLE = "WWWWW\nO0 1P\nW   X\nWWWWW\nWBWWW"  # the plate pile is walled off


def rss_mib(pid: int) -> float:
    return int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * PAGE / 2**20


def start_server(overrides: list[str]) -> tuple[subprocess.Popen, str]:
    cmd = [sys.executable, "-m", "services.level_server", "port=0", "metrics_port=-1", "seed=0",
           "curriculum.enabled=true", *overrides]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert proc.stdout is not None
    log: list[str] = []
    for line in proc.stdout:
        log.append(line)
        if "ready on" in line:
            threading.Thread(target=lambda: log.extend(proc.stdout or ()), daemon=True).start()
            return proc, line.split("ready on ")[1].strip()
    raise RuntimeError("the level server exited before it was ready:\n" + "".join(log))


def attack_payloads() -> list[tuple[str, str, bytes]]:
    """(kind, method, raw request) for each attack, built once."""
    kitchen = to_ascii(from_ascii("WWPWW\nO0 1O\nW   W\nWBWXW"))
    heldout = stack_levels([lv for _, lv in heldout_levels()])
    return [
        ("ascii_4MiB", "ValidateLevel", pb.ValidateLevelRequest(ascii="W" * (4 << 20)).SerializeToString()),
        ("ascii_1MiB", "ValidateLevel",
         pb.ValidateLevelRequest(ascii="W" * ((1 << 20) - 1024)).SerializeToString()),
        ("ascii_5000", "ValidateLevel", pb.ValidateLevelRequest(ascii="W" * 5000).SerializeToString()),
        ("kitchen", "ValidateLevel", pb.ValidateLevelRequest(ascii=kitchen).SerializeToString()),
        ("poison_heldout", "ReportScores",
         pb.ReportScoresRequest(levels=encode(heldout), scores=[1e6] * 105).SerializeToString()),
        ("poison_unsolvable", "ReportScores",
         pb.ReportScoresRequest(levels=encode(from_ascii(UNSOLVABLE)), scores=[1e6]).SerializeToString()),
    ]  # fmt: skip


def attacker(
    address: str, payloads: list, stop: threading.Event, codes: Counter, lock: threading.Lock
) -> None:
    with LevelClient(address) as client:
        calls = {
            m: client.channel.unary_unary(f"/{SERVICE_NAME}/{m}") for m in ("ValidateLevel", "ReportScores")
        }
        i = 0
        while not stop.is_set():
            kind, method, raw = payloads[i % len(payloads)]
            i += 1
            try:
                calls[method](raw, timeout=30)
                code = "OK"
            except grpc.RpcError as err:
                code = err.code().name
            with lock:
                codes[(kind, code)] += 1


def normal_client(address: str, stop: threading.Event, interval: float, out: list[float]) -> None:
    with LevelClient(address) as client:
        while not stop.is_set():
            t0 = time.perf_counter()
            client.get_levels(64)
            out.append(time.perf_counter() - t0)
            time.sleep(max(0.0, interval - (time.perf_counter() - t0)))


def percentiles(times: list[float]) -> dict[str, float]:
    a = np.sort(np.asarray(times)) * 1e3
    return {"calls": len(a), "p50_ms": float(np.percentile(a, 50)), "p99_ms": float(np.percentile(a, 99)),
            "max_ms": float(a[-1])}  # fmt: skip


def window(address: str, pid: int, seconds: float, interval: float, attackers: int = 0) -> dict:
    """The normal client's latency over `seconds`, with `attackers` connections attacking meanwhile."""
    payloads = attack_payloads() if attackers else []
    stop, lock, codes, times = threading.Event(), threading.Lock(), Counter(), []
    threads = [threading.Thread(target=normal_client, args=(address, stop, interval, times))]
    threads += [threading.Thread(target=attacker, args=(address, payloads, stop, codes, lock))
                for _ in range(attackers)]  # fmt: skip
    for t in threads:
        t.start()
    rss, t0 = [], time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        time.sleep(0.5)
        rss.append(rss_mib(pid))
    stop.set()
    for t in threads:
        t.join()
    out = percentiles(times)
    out["rss_mib_max"] = max(rss)
    if attackers:
        out["answers"] = {f"{kind} {code}": n for (kind, code), n in sorted(codes.items())}
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the attack")
    parser.add_argument("--attackers", type=int, default=12, help="concurrent attacking connections")
    parser.add_argument("--baseline", type=float, default=10.0, help="quiet latency window before the attack")
    parser.add_argument("--settle", type=float, default=10.0, help="quiet seconds after it")
    parser.add_argument(
        "--interval", type=float, default=0.02, help="seconds between the normal client's calls"
    )
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="server config override"
    )
    parser.add_argument("--out", default="", help="write the figures as JSON here too")
    args = parser.parse_args()
    result: dict = {"date": datetime.date.today().isoformat(), "machine": machine(), "git": git_rev(),
                    "args": vars(args)}  # fmt: skip

    proc, address = start_server(args.set)
    try:
        print(f"server pid {proc.pid} on {address}", flush=True)
        with LevelClient(address) as client:  # warm-up: connections, first chunks, every path once
            for _ in range(50):
                client.get_levels(64)
            client.validate(UNSOLVABLE)
        time.sleep(2)
        rss_start = rss_mib(proc.pid)
        base = result["baseline"] = window(address, proc.pid, args.baseline, args.interval)
        print(f"quiet: GetLevels(64) p50 {base['p50_ms']:.1f} ms, p99 {base['p99_ms']:.1f} ms over "
              f"{base['calls']} calls; server RSS {rss_start:.0f} MiB", flush=True)  # fmt: skip
        print(f"attack: {args.attackers} connections for {args.seconds:.0f} s ...", flush=True)
        a = result["attack"] = window(address, proc.pid, args.seconds, args.interval, args.attackers)
        print(f"attack: GetLevels(64) p50 {a['p50_ms']:.1f} ms, p99 {a['p99_ms']:.1f} ms, max "
              f"{a['max_ms']:.1f} ms over {a['calls']} calls; server RSS max {a['rss_mib_max']:.0f} MiB",
              flush=True)  # fmt: skip
        for key, n in a["answers"].items():
            print(f"  {key}: {n:,}", flush=True)
        time.sleep(args.settle)
        rss_end = rss_mib(proc.pid)
        after = result["after"] = window(address, proc.pid, args.baseline, args.interval)
        result["rss_mib"] = {"start": rss_start, "max": a["rss_mib_max"], "end": rss_end,
                             "end_vs_start": rss_end / rss_start - 1}  # fmt: skip
        growth = rss_end / rss_start - 1
        print(f"after {args.settle:.0f} s quiet: server RSS {rss_end:.0f} MiB ({growth:+.1%} of the start); "
              f"GetLevels(64) p99 {after['p99_ms']:.1f} ms", flush=True)  # fmt: skip
    finally:
        proc.terminate()
        proc.wait(30)

    failures = []
    if a["p99_ms"] >= 100:
        failures.append(f"GetLevels p99 under attack {a['p99_ms']:.1f} ms >= 100 ms")
    if result["rss_mib"]["end_vs_start"] > 0.10:
        failures.append(
            f"RSS after the attack {result['rss_mib']['end_vs_start']:+.1%} of its start (> +10%)"
        )
    if bad := {k: n for k, n in a["answers"].items() if k.endswith((" INTERNAL", " UNKNOWN"))}:
        failures.append(f"INTERNAL/UNKNOWN answers: {bad}")
    if poisoned := {k: n for k, n in a["answers"].items() if k.startswith("poison") and k.endswith(" OK")}:
        failures.append(f"poisoning attempts accepted: {poisoned}")
    result["failures"] = failures
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.out}")
    print("targets met" if not failures else "TARGETS MISSED: " + "; ".join(failures), flush=True)
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
