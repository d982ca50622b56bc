"""A bounded soak of `cec play`'s join limits over loopback (issue 23): anonymous joins past the old
file-descriptor limit, a chunked upload far past the body limit, malformed round messages.

    python benchmarks/play_joins_soak.py                  # ~1 minute on 2 CPU cores (JAX warm-up included)
    python benchmarks/play_joins_soak.py --joins 5000 --set limits.max_active_participants=2000

The script lowers its RLIMIT_NOFILE to `--nofile` (256; the server inherits it), then starts
`python -m services.play serve configs/study/tiny.yaml` on a free loopback port with its records in a
temporary folder and the study's default limits (override with `--set KEY=VALUE`). Each client request
binds its own source address in 127.0.0.0/8, so the server sees distinct client addresses.

1. One address asks for `--joins` / 10 participants: admitted up to its burst
   (`limits.joins_per_address_per_minute`), 429 beyond.
2. `--addresses` addresses ask for the rest, 8 at a time: admitted up to
   `limits.max_active_participants` in all, 503 beyond.
3. A participant admitted in 1 goes on: GET /api/state, the consent form, the info form.
4. A 256 MB chunked body to /api/submit (stopping when the answer arrives): 413, bytes sent, server RSS.
5. Round messages: a 5,000-level nested one (an error reply, the round goes on), a binary frame (close 1003).

Throughout, the server's open descriptors (/proc/PID/fd) and RSS are sampled every 50 joins. Any 500, any
traceback in the server's log, or any descriptor count near the limit fails the run (exit status 1).
"""

from __future__ import annotations

import argparse
import datetime
import http.client
import json
import os
import re
import resource
import select
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

try:  # run as a script (benchmarks/ on sys.path) or as a module
    from env_throughput import git_rev, machine  # type: ignore[import-not-found]
except ImportError:  # pragma: no cover
    from benchmarks.env_throughput import git_rev, machine

ROOT = Path(__file__).resolve().parents[1]
PAGE = os.sysconf("SC_PAGE_SIZE")


def rss_mib(pid: int) -> float:
    return int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * PAGE / 2**20


def open_fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def start_server(data: str, overrides: list[str], log: Any) -> tuple[subprocess.Popen[str], int]:
    # a practice round long enough for phase 5 (24 steps at 12 ticks/s would end in 2 s)
    cmd = [sys.executable, "-m", "services.play", "serve", "configs/study/tiny.yaml", "practice.steps=600",
           *overrides, "--host", "127.0.0.1", "--port", "0", "--data", data]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=log, text=True)
    assert proc.stdout is not None
    for line in proc.stdout:
        m = re.search(r"at http://127\.0\.0\.1:(\d+)/", line)
        if m:
            return proc, int(m.group(1))
    raise RuntimeError("the play server exited before it was serving (see its log)")


class Client:
    """HTTP over loopback from a chosen source address, one connection per request."""

    def __init__(self, port: int) -> None:
        self.port = port

    def request(
        self, method: str, path: str, source: str, body: bytes = b"", cookie: str = ""
    ) -> tuple[int, dict[str, str], Any, float]:
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30, source_address=(source, 0))
        headers = {"Content-Type": "application/json", "Connection": "close"}
        if cookie:
            headers["Cookie"] = f"cec_play={cookie}"
        t0 = time.perf_counter()
        try:
            conn.request(method, path, body=body if method == "POST" else None, headers=headers)
            res = conn.getresponse()
            raw = res.read()
            elapsed = time.perf_counter() - t0
            answer = json.loads(raw) if res.getheader("content-type") == "application/json" else raw.decode()
            return res.status, {k.lower(): v for k, v in res.getheaders()}, answer, elapsed
        finally:
            conn.close()


class Sampler:
    """The server's descriptors and RSS, sampled on demand."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.fds: list[int] = []
        self.rss: list[float] = []
        self.lock = threading.Lock()

    def sample(self) -> None:
        with self.lock:
            self.fds.append(open_fds(self.pid))
            self.rss.append(rss_mib(self.pid))


def pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(q * len(s)))] if s else float("nan")


def joins(client: Client, sources: list[str], sampler: Sampler, workers: int) -> dict[str, Any]:
    """POST /api/join once per source; statuses (0: no answer), the admitted's cookies, latencies."""
    statuses: Counter[int] = Counter()
    limits: Counter[str] = Counter()
    cookies: list[str] = []
    latency: dict[str, list[float]] = {"admitted": [], "refused": []}
    done = [0]
    lock = threading.Lock()

    def one(source: str) -> None:
        try:
            status, headers, answer, elapsed = client.request("POST", "/api/join", source, b"{}")
        except OSError:  # no answer at all (reset, refused, timed out): counted as status 0
            status, headers, answer, elapsed = 0, {}, None, float("nan")
        with lock:
            statuses[status] += 1
            if status == 200:
                cookies.append(re.search(r"cec_play=([^;]+)", headers["set-cookie"]).group(1))  # type: ignore[union-attr]
                latency["admitted"].append(elapsed)
            else:
                latency["refused"].append(elapsed)
                if isinstance(answer, dict) and "limit" in answer:
                    limits[f"{status} {answer['limit']}"] += 1
            done[0] += 1
            if done[0] % 50 == 0:
                sampler.sample()

    with ThreadPoolExecutor(workers) as pool:
        list(pool.map(one, sources))
    return {"statuses": dict(statuses), "limits": dict(limits), "cookies": cookies, "latency": latency}


def chunked_upload(port: int, cookie: str, total: int, sampler: Sampler) -> dict[str, Any]:
    """Sends a chunked body of `total` bytes to /api/submit until the server answers; what it answered."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=30)
    head = (
        "POST /api/submit HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
        f"Cookie: cec_play={cookie}\r\nTransfer-Encoding: chunked\r\n\r\n"
    )
    data = b" " * 65_536
    chunk = f"{len(data):x}\r\n".encode() + data + b"\r\n"
    rss0 = rss_mib(sampler.pid)
    peak = rss0
    sent = 0
    t0 = time.perf_counter()
    response = b""
    try:
        sock.sendall(head.encode())
        while sent < total:
            if select.select([sock], [], [], 0)[0]:
                break  # the answer is there
            sock.sendall(chunk)
            sent += len(data)
            if sent % (8 * 2**20) == 0:
                peak = max(peak, rss_mib(sampler.pid))
        else:
            sock.sendall(b"0\r\n\r\n")
        while b"\r\n\r\n" not in response:
            part = sock.recv(65_536)
            if not part:
                break
            response += part
    except (BrokenPipeError, ConnectionResetError) as err:
        response = response or f"connection closed ({err})".encode()
    finally:
        sock.close()
    elapsed = time.perf_counter() - t0
    peak = max(peak, rss_mib(sampler.pid))
    status_line = response.split(b"\r\n", 1)[0].decode(errors="replace")
    return {
        "status_line": status_line,
        "bytes_sent_before_the_answer": sent,
        "seconds": round(elapsed, 3),
        "server_rss_mib_before": round(rss0, 1),
        "server_rss_mib_peak": round(peak, 1),
        "server_rss_mib_after": round(rss_mib(sampler.pid), 1),
    }


def round_messages(port: int, client: Client, cookie: str, source: str) -> dict[str, Any]:
    """Takes a participant to the practice round and sends it a deeply nested message, then a binary frame."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    for form in (
        {"stage": "consent", "accept": True},
        {"stage": "info", "fields": {"worker_id": "soak1234"}},
        {"stage": "instructions"},
    ):
        status, _, view, _ = client.request("POST", "/api/submit", source, json.dumps(form).encode(), cookie)
        assert status == 200, (status, view)
    out: dict[str, Any] = {}
    url = f"ws://127.0.0.1:{port}/ws/round"
    with connect(url, additional_headers={"Cookie": f"cec_play={cookie}"}, open_timeout=30) as ws:
        assert json.loads(ws.recv(timeout=30))["type"] == "start"
        ws.send('{"type": "key", "seq": ' + "[" * 1000 + "]" * 1000 + ', "action": 1}')  # 2 KB, under 4 KB
        ws.send('{"type": "key", "seq": 1, "action": ' + "1" * 3000 + "}")
        replies: list[dict[str, Any]] = []
        while len([r for r in replies if r["type"] == "error"]) < 2:
            replies.append(json.loads(ws.recv(timeout=30)))
        out["nested_and_long_number"] = [r["message"] for r in replies if r["type"] == "error"]
        out["frames_during"] = sum(r["type"] == "frame" for r in replies)
        ws.send(b"\x00\x01binary")
        try:
            while True:
                ws.recv(timeout=30)
        except ConnectionClosed as closed:
            out["binary_frame_close"] = [closed.rcvd.code, closed.rcvd.reason] if closed.rcvd else None
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--joins", type=int, default=2000, help="joins in all (a tenth from one address)")
    parser.add_argument("--addresses", type=int, default=100, help="client addresses of phase 2")
    parser.add_argument("--nofile", type=int, default=256, help="RLIMIT_NOFILE of the script and the server")
    parser.add_argument("--upload-mib", type=int, default=256, help="size of the chunked body of phase 4")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="study override")
    parser.add_argument("--out", default=str(ROOT / "benchmarks/results/play_joins_soak_cpu_2cpu.json"))
    args = parser.parse_args()

    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (args.nofile, hard))
    result: dict[str, Any] = {
        "date": datetime.date.today().isoformat(),
        "machine": machine(),
        "git": git_rev(),
        "command": " ".join([Path(sys.argv[0]).as_posix(), *sys.argv[1:]]),
        "rlimit_nofile": args.nofile,
        "overrides": args.set,
    }
    failures: list[str] = []
    with tempfile.TemporaryDirectory(prefix="cec-play-soak-") as tmp:
        log_path = Path(tmp) / "server.log"
        with open(log_path, "w") as log:
            t_start = time.perf_counter()
            proc, port = start_server(str(Path(tmp) / "records"), args.set, log)
            try:
                print(f"server pid {proc.pid} on 127.0.0.1:{port} (RLIMIT_NOFILE {args.nofile}), "
                      f"up in {time.perf_counter() - t_start:.1f} s", flush=True)  # fmt: skip
                client = Client(port)
                sampler = Sampler(proc.pid)
                sampler.sample()
                fds0, rss0 = sampler.fds[0], sampler.rss[0]
                t0 = time.perf_counter()
                one = args.joins // 10
                hammer = joins(client, ["127.0.0.2"] * one, sampler, 4)
                spread = [f"127.0.1.{1 + i % args.addresses}" for i in range(args.joins - one)]
                many = joins(client, spread, sampler, 8)
                elapsed = time.perf_counter() - t0
                sampler.sample()
                result["phase1_one_address"] = {k: v for k, v in hammer.items() if k != "cookies"}
                result["phase2_many_addresses"] = {k: v for k, v in many.items() if k != "cookies"}
                all_lat = {k: hammer["latency"][k] + many["latency"][k] for k in ("admitted", "refused")}
                statuses = Counter(hammer["statuses"]) + Counter(many["statuses"])
                result["joins"] = {
                    "sent": args.joins,
                    "seconds": round(elapsed, 2),
                    "statuses": dict(sorted(statuses.items())),
                    "admitted_ms_p50_p99": [round(1e3 * pct(all_lat["admitted"], q), 1) for q in (0.5, 0.99)],
                    "refused_ms_p50_p99": [round(1e3 * pct(all_lat["refused"], q), 1) for q in (0.5, 0.99)],
                    "server_fds_start_max_end": [fds0, max(sampler.fds), sampler.fds[-1]],
                    "server_rss_mib_start_max_end": [round(x, 1) for x in (rss0, max(sampler.rss),
                                                                           sampler.rss[-1])],
                    "record_files": len(list((Path(tmp) / "records" / "tiny").glob("p*.jsonl"))),
                }  # fmt: skip
                for key in ("latency",):
                    result["phase1_one_address"].pop(key)
                    result["phase2_many_addresses"].pop(key)
                j = result["joins"]
                print(f"joins: {args.joins} in {j['seconds']} s -> statuses {j['statuses']}", flush=True)
                print(f"  one address ({one}): {hammer['statuses']} {hammer['limits']}", flush=True)
                print(f"  {args.addresses} addresses ({len(spread)}): {many['statuses']} {many['limits']}",
                      flush=True)  # fmt: skip
                print(f"  latency ms p50/p99: admitted {j['admitted_ms_p50_p99']}, refused "
                      f"{j['refused_ms_p50_p99']}", flush=True)  # fmt: skip
                print(f"  server fds start/max/end {j['server_fds_start_max_end']}, RSS MiB start/max/end "
                      f"{j['server_rss_mib_start_max_end']}, record files {j['record_files']}",
                      flush=True)  # fmt: skip
                if statuses.get(500) or set(statuses) - {200, 429, 503}:
                    failures.append(f"unexpected statuses {dict(statuses)}")
                if max(sampler.fds) > args.nofile - 32:
                    failures.append(f"server descriptors reached {max(sampler.fds)} of {args.nofile}")

                cookie = hammer["cookies"][0]
                status, _, view, took = client.request("GET", "/api/state", "127.0.0.2", cookie=cookie)
                result["admitted_participant_goes_on"] = {"status": status, "stage": view.get("stage"),
                                                          "ms": round(1e3 * took, 1)}  # fmt: skip
                print(f"an admitted participant: GET /api/state {status} ({view.get('stage')}) in "
                      f"{1e3 * took:.1f} ms", flush=True)  # fmt: skip
                if status != 200:
                    failures.append(f"an admitted participant got {status}")

                upload = chunked_upload(port, hammer["cookies"][1], args.upload_mib * 2**20, sampler)
                result["chunked_upload"] = {"mib_offered": args.upload_mib, **upload}
                print(f"chunked {args.upload_mib} MiB body: {upload['status_line']!r} after "
                      f"{upload['bytes_sent_before_the_answer']:,} bytes sent ({upload['seconds']} s); RSS "
                      f"{upload['server_rss_mib_before']} -> peak {upload['server_rss_mib_peak']} -> "
                      f"{upload['server_rss_mib_after']} MiB", flush=True)  # fmt: skip
                if " 413 " not in upload["status_line"] + " ":
                    failures.append(f"the chunked body got {upload['status_line']!r}")

                try:
                    ws = round_messages(port, client, cookie, "127.0.0.2")
                except Exception as err:  # the server did not play along: a figure, not the end of the run
                    ws = {"nested_and_long_number": None, "binary_frame_close": None, "error": repr(err)}
                result["round_messages"] = ws
                print(f"round: nested/long-number messages -> {ws['nested_and_long_number']}; "
                      f"binary frame -> close {ws['binary_frame_close']}", flush=True)  # fmt: skip
                if not ws["binary_frame_close"] or ws["binary_frame_close"][0] != 1003:
                    failures.append(f"the binary frame got {ws['binary_frame_close']}")
                sampler.sample()
                result["server_fds_end"] = sampler.fds[-1]
                result["server_rss_mib_end"] = round(sampler.rss[-1], 1)
            finally:
                proc.terminate()
                proc.wait(30)
        server_log = log_path.read_text()
    tracebacks = server_log.count("Traceback")
    result["server_log"] = {
        "tracebacks": tracebacks,
        "lines": server_log.count("\n"),
        "warnings": [line for line in server_log.splitlines() if " WARNING " in line][:10],
    }
    print(f"server log: {tracebacks} tracebacks, {server_log.count(chr(10))} lines", flush=True)
    if tracebacks:
        failures.append(f"{tracebacks} tracebacks in the server's log")
    result["failures"] = failures
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")
    for f in failures:
        print(f"FAIL: {f}", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
