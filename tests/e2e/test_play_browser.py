"""`cec play` end to end: a real server process, a real Redis, real headless Chromium driven by Selenium.

One server (configs/study/tiny.yaml: a 30-step real-time practice round, one 20-step turn-based round with a
random `small` network, the 7-item survey) records to files and to Redis. The tests play it with key
presses in the browser and then read the records back from both stores.

Needs Debian's `chromium` and `chromium-driver` (.ci/run installs them); without them the tests are skipped
locally and fail under CI.
"""

from __future__ import annotations

import asyncio
import http.cookiejar
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from websockets.asyncio.client import connect as ws_connect
from websockets.exceptions import InvalidStatus
from websockets.typing import Origin

from cec.evaluation.results import read_csv
from services.play.export import finished_rounds
from services.play.recording import FileStore, RedisStore
from services.store import LocalRedis, StoreConfig
from tests.play_server import PlayServer

webdriver = pytest.importorskip("selenium.webdriver")
from selenium.webdriver.chrome.service import Service  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.common.keys import Keys  # noqa: E402
from selenium.webdriver.support import expected_conditions as EC  # noqa: E402, N812
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
STUDY = ROOT / "configs" / "study" / "tiny.yaml"
ARROWS = {0: Keys.ARROW_UP, 1: Keys.ARROW_DOWN, 2: Keys.ARROW_RIGHT, 3: Keys.ARROW_LEFT, 4: "x", 5: " "}
# Seat 0 in Cramped Room: fetch onions from the pile on the left and put them in the pot above-right.
TURNS_A = [3, 5, 2, 0, 5, 3, 3, 5, 2, 0, 5, 3, 3, 5, 2, 0, 5, 4, 1, 2]
TURNS_B = [2, 2, 1, 3, 4, 5, 0, 3, 1, 2, 5, 4, 4, 0, 3, 1, 2, 5, 3, 0]
WAIT_S = 30.0


def _browser_paths() -> tuple[str, str]:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if not (chromium and driver):
        message = "headless Chromium not installed (Debian: apt-get install chromium chromium-driver)"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    return chromium, driver


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, redis_server: LocalRedis) -> Iterator[dict[str, Any]]:
    """`python -m services.play serve` on a free port, recording to files and Redis."""
    _browser_paths()
    data = tmp_path_factory.mktemp("play_data")
    args = [str(STUDY), "--port", "0", "--data", str(data), "--redis-url", redis_server.url]
    try:
        server = PlayServer(args, "tiny")
    except RuntimeError as err:
        pytest.fail(str(err))
    yield {"url": server.url, "data": data, "redis": redis_server, "log": server.lines}
    server.stop(timeout=20)


def _new_browser() -> Any:
    chromium, driver = _browser_paths()
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=820,760"):
        opts.add_argument(arg)
    return webdriver.Chrome(service=Service(driver), options=opts)


class Player:
    """One participant in one browser."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.d = _new_browser()
        self.wait = WebDriverWait(self.d, WAIT_S, poll_frequency=0.02)

    def close(self) -> None:
        self.d.quit()

    def click(self, element_id: str) -> None:
        self.wait.until(EC.element_to_be_clickable((By.ID, element_id))).click()

    def stage(self, name: str) -> None:
        self.wait.until(lambda d: d.find_element(By.ID, "app").get_attribute("data-stage") == name)

    def stats(self) -> dict[str, Any]:
        stats: dict[str, Any] = self.d.execute_script("return window.cecStats")
        return stats

    def press(self, action: int) -> None:
        self.d.find_element(By.TAG_NAME, "body").send_keys(ARROWS[action])

    def join(self, worker_id: str) -> None:
        self.d.get(self.url)
        self.click("start")
        self.stage("consent")
        self.click("consent-accept")
        self.stage("info")
        self.d.find_element(By.ID, "info-worker_id").send_keys(worker_id)
        self.click("info-submit")
        self.stage("instructions")
        self.click("instructions-continue")
        self.stage("round")

    def enter_free_play(self) -> None:
        """Opens the page and passes its start and instructions (free play asks no consent)."""
        self.d.get(self.url)
        self.click("start")
        self.stage("instructions")
        self.click("instructions-continue")

    def start_round(self) -> None:
        self.click("round-start")
        self.wait.until(EC.presence_of_element_located((By.ID, "board")))

    def real_time_keys(self, actions: list[int]) -> None:
        for a in actions:
            self.press(a)
            time.sleep(0.15)

    def turn(self, i: int, action: int) -> None:
        """Presses key `i` (0-based) of a turn-based round and waits for the server's reply to it."""
        self.press(action)
        self.wait.until(lambda d: len(d.execute_script("return window.cecStats.roundTrip")) >= i + 1)

    def finish_round(self) -> None:
        self.click("round-continue")

    def survey(self, answers: dict[str, int]) -> None:
        self.stage("survey")
        for item, value in answers.items():
            self.d.find_element(By.ID, f"q-{item}-{value}").click()
        self.click("survey-submit")
        self.stage("done")


SURVEY_A = {
    "adapted": 4,
    "consistent": 3,
    "human_like": 2,
    "in_my_way": 5,
    "frustrating": 1,
    "enjoyed": 4,
    "coordination": 3,
}
SURVEY_B = {
    "adapted": 1,
    "consistent": 2,
    "human_like": 3,
    "in_my_way": 4,
    "frustrating": 5,
    "enjoyed": 1,
    "coordination": 2,
}


def _participant_of(store: FileStore | RedisStore, worker_id: str) -> str:
    ids = [
        p
        for p in store.participants()
        if any(ev.get("fields", {}).get("worker_id") == worker_id for ev in store.events(p))
    ]
    assert len(ids) == 1, f"{worker_id}: expected one participant, found {ids}"
    return ids[0]


def _check_records(
    server: dict[str, Any], worker_id: str, turns: list[int], answers: dict[str, int]
) -> dict[str, Any]:
    """Reads the participant's events from the files and from Redis, checks them, returns a summary."""
    files = FileStore(server["data"], "tiny")
    redis_store = RedisStore(StoreConfig(url=server["redis"].url), "tiny")
    try:
        pid = _participant_of(files, worker_id)
        events = files.events(pid)
        assert redis_store.events(pid) == events  # both stores hold the same log
    finally:
        files.close()
        redis_store.close()
    assert all(ev["participant"] == pid for ev in events)
    kinds = [ev["type"] for ev in events]
    assert kinds[:3] == ["participant", "consent", "info"] and kinds[-2:] == ["survey", "complete"]
    rounds = finished_rounds(pid, events)  # also checks step numbering and the end events' totals
    assert [(r.round, r.start["mode"], len(r.steps)) for r in rounds] == [
        (-1, "real_time", 24),
        (0, "turn_based", 20),
    ]
    practice, main = rounds
    # Turn-based: exactly the keys pressed, each with a reaction time; both seats' actions recorded.
    assert [s["human_action"] for s in main.steps] == turns
    assert all(s["actions"][0] == s["human_action"] and 0 <= s["actions"][1] < 6 for s in main.steps)
    assert all(isinstance(s["rt_ms"], float) for s in main.steps)
    assert main.end["return"] == sum(s["reward"] for s in main.steps)
    assert main.end["collisions"] == sum(s["collision"] for s in main.steps)
    # Real-time: one step per tick; the keys pressed arrive as actions with reaction times, STAY otherwise.
    keyed = [s for s in practice.steps if s["rt_ms"] is not None]
    assert keyed, "no key press of the real-time round was played"
    assert all(s["human_action"] == 4 for s in practice.steps if s["rt_ms"] is None)
    survey = next(ev for ev in events if ev["type"] == "survey")
    assert survey["round"] == 0 and survey["answers"] == answers
    return {"pid": pid, "main": main, "events": events}


def test_a_participant_plays_a_study_in_the_browser(server: dict[str, Any], tmp_path: Path) -> None:
    player = Player(server["url"])
    try:
        player.join("worker0001")
        # Practice: real time (10 ticks/s), a few keys while the partner keeps moving.
        player.start_round()
        player.real_time_keys([3, 5, 2])
        player.stage("round")
        player.wait.until(EC.element_to_be_clickable((By.ID, "round-continue")))
        real_time = player.stats()
        player.finish_round()
        # The study round: turn-based, one step per key press.
        player.stage("round")
        player.start_round()
        for i, action in enumerate(TURNS_A):
            player.turn(i, action)
            if i == 13:
                shot = player.d.get_screenshot_as_png()
                (tmp_path / "play.png").write_bytes(shot)
                if os.environ.get("CEC_PLAY_SCREENSHOT"):
                    Path(os.environ["CEC_PLAY_SCREENSHOT"]).write_bytes(shot)
        stats = player.stats()
        last_drawn = stats["lastState"]
        player.finish_round()
        player.survey(SURVEY_A)
        assert player.d.find_element(By.ID, "completion-code").text == "TINY-DONE"
    finally:
        player.close()

    # Every key of the turn-based round was drawn from the precomputed next states.
    assert stats["mode"] == "turn_based" and len(stats["keyToFrame"]) == len(TURNS_A)
    print(
        "\nkey press -> painted frame (turn-based, precomputed): "
        f"median {_median(stats['keyToFrame']):.1f} ms; "
        f"key press -> server reply: median {_median(stats['roundTrip']):.1f} ms over {len(TURNS_A)} keys; "
        f"real time at 12 ticks/s: key press -> the frame of the tick that played it: median "
        f"{_median(real_time['keyToFrame']):.1f} ms over {len(real_time['keyToFrame'])} keys"
    )
    rec = _check_records(server, "worker0001", TURNS_A, SURVEY_A)
    assert rec["main"].steps[-1]["state"] == last_drawn  # the browser showed what was recorded

    # Export: the human-AI round lands in the evaluator's result table.
    out = tmp_path / "export"
    cmd = [sys.executable, "-m", "services.play", "export", str(STUDY), "--data", str(server["data"])]
    done = subprocess.run([*cmd, "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    table = read_csv(out / "results.csv")
    mine = table.select(table.policy_a == rec["pid"])
    assert len(mine) == 1
    assert (
        mine.algorithm_a[0] == "human"
        and mine.policy_b[0] == "random_small"
        and mine.level[0] == "cramped_room"
    )
    assert mine.episode_steps[0] == 20 and mine.returns[0] == rec["main"].end["return"]
    assert mine.collisions[0] == rec["main"].end["collisions"]
    survey_rows = (out / "survey.csv").read_text().splitlines()
    assert sum(rec["pid"] in row for row in survey_rows) == 7


def test_two_concurrent_participants_do_not_interfere(server: dict[str, Any]) -> None:
    a, b = Player(server["url"]), Player(server["url"])
    try:
        a.join("workerAAAA")
        b.join("workerBBBB")
        a.start_round()  # both real-time practice rounds run at the same time
        b.start_round()
        for _ in range(2):
            a.press(3)
            b.press(2)
            time.sleep(0.2)
        a.finish_round()
        b.finish_round()
        a.stage("round")
        b.stage("round")
        a.start_round()
        b.start_round()
        for i in range(len(TURNS_A)):  # interleaved turn-based rounds with different keys
            a.turn(i, TURNS_A[i])
            b.turn(i, TURNS_B[i])
        a.finish_round()
        b.finish_round()
        a.survey(SURVEY_A)
        b.survey(SURVEY_B)
    finally:
        a.close()
        b.close()
    rec_a = _check_records(server, "workerAAAA", TURNS_A, SURVEY_A)
    rec_b = _check_records(server, "workerBBBB", TURNS_B, SURVEY_B)
    assert rec_a["pid"] != rec_b["pid"]


def _median(xs: list[float]) -> float:
    s = sorted(xs)
    return s[len(s) // 2] if s else float("nan")


BAD_MESSAGES = (
    "{not json",
    "[1, 2]",
    '{"type": "key", "seq": 1, "action": 9}',
    '{"type": "key", "seq": 1, "action": true}',
    '{"type": "key", "seq": "1", "action": 1}',
    '{"type": "key", "seq": 1, "action": 1, "rt_ms": -5}',
    '{"type": "act", "t": 0}',
)


def test_the_server_validates_what_clients_send(server: dict[str, Any]) -> None:
    """Without a browser: the HTTP and WebSocket endpoints refuse malformed, oversized and foreign input."""
    base = server["url"].rstrip("/")
    jar = http.cookiejar.CookieJar()
    opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(jar))

    def post(path: str, body: bytes, content_type: str = "application/json") -> tuple[int, dict[str, Any]]:
        req = urllib.request.Request(base + path, data=body, headers={"Content-Type": content_type})
        try:
            with opener.open(req) as res:
                return res.status, json.loads(res.read())
        except urllib.error.HTTPError as err:
            return err.code, json.loads(err.read())

    assert post("/api/submit", b'{"stage": "consent", "accept": true}')[0] == 401  # no session
    assert post("/api/join", b"{}", "text/plain")[0] == 415  # what a cross-site form would send
    status, view = post("/api/join", b"{}")
    assert (
        status == 200 and view["stage"] == "consent" and re.fullmatch(r"p[0-9a-f]{20}", view["participant"])
    )
    cookie = next(c for c in jar if c.name == "cec_play")
    assert cookie.has_nonstandard_attr("HttpOnly") and str(cookie.value) not in json.dumps(view)
    assert post("/api/submit", b"not json")[0] == 400
    assert (
        post("/api/submit", b'{"stage": "consent", "accept": "' + b"x" * 20_000 + b'"}')[0] == 413
    )  # too large
    assert post("/api/submit", b'{"stage": "survey", "round": 0, "answers": {}}')[1]["error"].startswith(
        "this participant is at stage 'consent'"
    )
    post("/api/submit", b'{"stage": "consent", "accept": true}')
    post("/api/submit", b'{"stage": "info", "fields": {"worker_id": "workerC"}}')
    assert post("/api/submit", b'{"stage": "instructions"}')[1]["stage"] == "round"

    ws_url = base.replace("http://", "ws://") + "/ws/round"
    headers = {"Cookie": f"cec_play={cookie.value}"}

    async def talk() -> list[dict[str, Any]]:
        with pytest.raises(InvalidStatus):  # another site's page may not connect
            async with ws_connect(ws_url, additional_headers=headers, origin=Origin("http://evil.example")):
                pass
        replies: list[dict[str, Any]] = []
        async with ws_connect(ws_url, additional_headers=headers) as ws:
            start = json.loads(await ws.recv())
            assert start["type"] == "start" and start["mode"] == "real_time"
            for bad in BAD_MESSAGES:
                await ws.send(bad)
            while (
                len([r for r in replies if r["type"] == "error"]) < len(BAD_MESSAGES)
                or replies[-1]["type"] != "end"
            ):
                replies.append(json.loads(await ws.recv()))
        return replies

    replies = asyncio.run(talk())
    assert sum(r["type"] == "error" for r in replies) == len(BAD_MESSAGES)  # each answered, none played
    frames = [r for r in replies if r["type"] == "frame"]
    assert [f["t"] for f in frames] == list(range(1, 25)) and all("ack" not in f for f in frames)
    with urllib.request.urlopen(base + "/metrics") as res:
        assert "cec_play_steps_total" in res.read().decode()


def test_a_scripted_person_cooks_with_the_shipped_cec_partner_in_default_free_play(tmp_path: Path) -> None:
    """The README's play command with its defaults (`cec play serve --partner cec`: Cramped Room, a 200-step
    turn-based round, sampled agent actions, the agent giving way after 3 collisions) played in the browser
    by a "person" who cooks like the scripted cook but never gives way (greedy, no random moves), reading the
    state on screen (`window.cecStats.lastState`) and pressing arrow keys. The team must score: the shipped
    agent may not freeze or block the person for a whole round. (Without giving way, shipped seed 201 and
    this person lock up in 10 rounds of 24; with it none of 96 rounds with the four seeds scores 0:
    benchmarks/results/overcooked/shipped/README.md, "With a person".)"""
    import jax

    from cec.envs.overcooked.scripted import scripted_actions
    from cec.levels.named import resolve_level
    from services.play.game import expand_state

    _browser_paths()
    server = PlayServer(["--partner", "cec", "--port", "0", "--data", str(tmp_path)], None)
    _, level = resolve_level("cramped_room", ROOT, np.random.default_rng(0))
    key = jax.random.PRNGKey(0)
    cook = jax.jit(lambda state, t: scripted_actions(jax.random.fold_in(key, t), state, 0.0, False))
    player = Player(server.url)
    try:
        player.enter_free_play()
        player.stage("round")
        player.start_round()
        seat_class = player.d.find_element(By.CSS_SELECTOR, ".hud span[class^=you-]").get_attribute("class")
        seat = int(seat_class.removeprefix("you-"))
        for i in range(200):
            state = expand_state(player.stats()["lastState"], level)
            player.turn(i, int(cook(state, i)[seat]))
        player.wait.until(EC.text_to_be_present_in_element((By.ID, "hint"), "Round over"))
        hint = player.d.find_element(By.ID, "hint").text
    finally:
        player.close()
        code = server.stop(signal.SIGINT)
    assert code == 0 and "Traceback" not in server.log, server.log
    files = FileStore(tmp_path, server.study)
    try:
        ((pid,),) = [files.participants()]
        (rnd,) = finished_rounds(pid, files.events(pid))
    finally:
        files.close()
    score = rnd.end["return"]
    assert f"Team score: {score:g}." in hint
    agent_actions = [s["actions"][1 - seat] for s in rnd.steps]
    assert len(rnd.steps) == 200 and score > 0, (score, agent_actions)
    assert rnd.start["agent_gives_way_after"] == 3
