"""Throughput, latency, CPU and memory of the level server over loopback.

    python benchmarks/level_server.py                      # ~5 minutes (3-minute soak) on 2 CPU cores
    python benchmarks/level_server.py --soak-seconds 30    # a quick look

The server runs as its own process (`python -m services.level_server`, default config), so its CPU time
and resident memory are read from /proc apart from the clients'. Clients are threads of this process using
the project's client library (each received batch is decoded into a NumPy `Level`, as a consumer would).

1. Peer, in the same run: the library generator called in-process (`generate_batch`, jitted, at the
   server's chunk size), the ceiling a server built on it can approach.
2. One client streaming (batch 4096): levels/s received, and the ratio to the peer.
3. 2, 4 and 8 concurrent streams (distinct seeds): aggregate levels/s.
4. Unary `GetLevels` latency for 1 and 64 levels (fresh levels from the server's sequence): p50 / p99.
5. Server CPU seconds per 1,000 levels streamed (from section 2's window).
6. Soak: 8 concurrent streams for `--soak-seconds`; the server's RSS sampled every 5 s (start, max, end,
   and the growth over the second half of the run, where a leak would show).
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
from pathlib import Path

import jax

from cec.levels.generator import generate_batch
from services.level_server.client import LevelClient

try:  # run as a script (benchmarks/ on sys.path) or as a module
    from env_throughput import git_rev, machine  # type: ignore[import-not-found]
except ImportError:  # pragma: no cover
    from benchmarks.env_throughput import git_rev, machine

ROOT = Path(__file__).resolve().parents[1]
PAGE = os.sysconf("SC_PAGE_SIZE")
TICK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK  # utime + stime


def rss_mib(pid: int) -> float:
    return int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * PAGE / 2**20


def start_server() -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.level_server", "port=0", "metrics_port=-1", "seed=0"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    for line in proc.stdout:
        if "ready on" in line:
            return proc, line.split("ready on ")[1].strip()
    raise RuntimeError("the level server exited before it was ready")


def peer_generator(chunk: int, seconds: float) -> float:
    fn = jax.jit(generate_batch, static_argnums=(1,))
    jax.block_until_ready(fn(jax.random.PRNGKey(0), chunk))
    n, i, t0 = 0, 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        jax.device_get(fn(jax.random.PRNGKey(i), chunk))
        n, i = n + chunk, i + 1
    return n / (time.perf_counter() - t0)


def stream_for(address: str, seed: int, batch: int, seconds: float, out: list[int]) -> None:
    with LevelClient(address) as client:
        n, t0 = 0, time.perf_counter()
        for _, levels in client.stream(seed=seed, batch_size=batch):
            n += int(levels.grid.shape[0])
            if time.perf_counter() - t0 > seconds:
                break
        out.append(n)


def concurrent(address: str, streams: int, batch: int, seconds: float, seed0: int) -> float:
    counts: list[int] = []
    threads = [threading.Thread(target=stream_for, args=(address, seed0 + i, batch, seconds, counts))
               for i in range(streams)]  # fmt: skip
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return sum(counts) / (time.perf_counter() - t0)


def latency(client: LevelClient, n: int, calls: int) -> dict[str, float]:
    for _ in range(20):
        client.get_levels(n)
    times = []
    for _ in range(calls):
        t0 = time.perf_counter()
        client.get_levels(n)
        times.append(time.perf_counter() - t0)
    times.sort()
    return {"p50_ms": 1e3 * times[len(times) // 2], "p99_ms": 1e3 * times[int(len(times) * 0.99)]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each throughput window")
    parser.add_argument("--soak-seconds", type=float, default=180.0)
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--calls", type=int, default=500, help="unary calls per latency figure")
    parser.add_argument("--out", default=str(ROOT / "benchmarks/results/level_server_cpu_2cpu.json"))
    args = parser.parse_args()
    result: dict = {"date": datetime.date.today().isoformat(), "machine": machine(), "git": git_rev()}

    proc, address = start_server()
    try:
        print(f"server pid {proc.pid} on {address}", flush=True)
        print("peer: in-process generate_batch(512) ...", flush=True)
        result["peer_generator_levels_per_s"] = peer = peer_generator(512, args.seconds)
        print(f"  {peer:,.0f} levels/s", flush=True)

        concurrent(address, 1, args.batch, 2.0, 10_000)  # warm-up (connections, first chunks)
        cpu0 = cpu_seconds(proc.pid)
        counts: list[int] = []
        t0 = time.perf_counter()
        stream_for(address, 1, args.batch, args.seconds, counts)
        one = counts[0] / (time.perf_counter() - t0)
        cpu = cpu_seconds(proc.pid) - cpu0
        result["one_stream_levels_per_s"] = one
        result["one_stream_vs_peer"] = one / peer
        result["server_cpu_s_per_1k_levels"] = 1000 * cpu / counts[0]
        ms = result["server_cpu_s_per_1k_levels"] * 1e3
        print(f"1 stream: {one:,.0f} levels/s ({one / peer:.2f}x the in-process generator); "
              f"server CPU {ms:.2f} ms per 1k levels", flush=True)  # fmt: skip

        result["concurrent_levels_per_s"] = {}
        for k in (2, 4, 8):
            rate = concurrent(address, k, args.batch, args.seconds, 100 * k)
            result["concurrent_levels_per_s"][str(k)] = rate
            print(f"{k} streams: {rate:,.0f} levels/s in total", flush=True)

        with LevelClient(address) as client:
            result["get_levels_latency"] = {str(n): latency(client, n, args.calls) for n in (1, 64)}
        for n, lat in result["get_levels_latency"].items():
            print(f"GetLevels({n}): p50 {lat['p50_ms']:.2f} ms, p99 {lat['p99_ms']:.2f} ms", flush=True)

        print(f"soak: 8 streams for {args.soak_seconds:.0f} s, server RSS every 5 s ...", flush=True)
        samples: list[tuple[float, float]] = []
        counts = []
        threads = [threading.Thread(target=stream_for, args=(address, 5000 + i, args.batch, args.soak_seconds,
                                                              counts)) for i in range(8)]  # fmt: skip
        t0 = time.perf_counter()
        for t in threads:
            t.start()
        while any(t.is_alive() for t in threads):
            samples.append((time.perf_counter() - t0, rss_mib(proc.pid)))
            time.sleep(5)
        for t in threads:
            t.join()
        dt = time.perf_counter() - t0
        half = [r for s, r in samples if s >= dt / 2]
        result["soak"] = {
            "seconds": dt,
            "levels": sum(counts),
            "levels_per_s": sum(counts) / dt,
            "rss_mib_start": samples[0][1],
            "rss_mib_max": max(r for _, r in samples),
            "rss_mib_end": samples[-1][1],
            "rss_mib_growth_second_half": (half[-1] - half[0]) if len(half) > 1 else 0.0,
            "rss_samples": samples,
        }
        s = result["soak"]
        print(f"soak: {s['levels']:,} levels ({s['levels_per_s']:,.0f}/s); RSS {s['rss_mib_start']:.0f} -> "
              f"max {s['rss_mib_max']:.0f} -> end {s['rss_mib_end']:.0f} MiB; second-half growth "
              f"{s['rss_mib_growth_second_half']:+.1f} MiB", flush=True)  # fmt: skip
    finally:
        proc.terminate()
        proc.wait(30)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
