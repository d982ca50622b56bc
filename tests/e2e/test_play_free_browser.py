"""Free play as a game, in headless Chromium through the entry point (`cec play serve`, a real process):
three rounds in a row in one visit, a reload in the middle of one and between two, the partner the person
chose, each round recorded once; the page's hint to step aside when the cooks bump head-on, which says
whether the partner has a free cell as the board shows it; and its hint when the cooks stand still, one in
the other's only way (a person in the pot's only access cell, the agent waiting).

Needs Debian's `chromium` and `chromium-driver` (skipped locally without them, failed under CI).
"""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from services.play.export import finished_rounds
from services.play.recording import FileStore
from tests.e2e.test_play_browser import EC, By, Player, _browser_paths
from tests.play_server import PlayServer

pytestmark = pytest.mark.slow

STEPS = 6
# Seat 0 at the mouth of seat 1's dead end: seat 1 can move only into seat 0's cell, so every step in which
# seat 0 walks east into it is a collision, whatever the agent does (a staged head-on block).
HEAD_ON = "WWWPWW\nO  01W\nWBWWXW\n"
# The same with a free cell east of seat 1. Seat 0 stands in the pot's only access cell, and in seat 1's only
# way to the pot, the onions and the plates (seat 1 in seat 0's to the serving window).
STANDOFF = "WWWPWWW\nO  01 W\nWBWWXWW\n"


def _play(player: Player, actions: list[int]) -> None:
    player.wait.until(EC.presence_of_element_located((By.ID, "board")))
    for i, action in enumerate(actions):
        player.turn(i, action)


def _round_page(player: Player, number: int) -> None:
    player.stage("round")
    player.wait.until(EC.text_to_be_present_in_element((By.TAG_NAME, "h1"), f"Round {number}"))


def _summary_rows(player: Player) -> list[list[str]]:
    rows = player.d.find_elements(By.CSS_SELECTOR, "#summary tr")[1:]
    return [[td.text for td in row.find_elements(By.TAG_NAME, "td")] for row in rows]


def test_three_free_play_rounds_in_one_visit_with_reloads(tmp_path: Path) -> None:
    _browser_paths()
    server = PlayServer(
        ["--partner", "cec", "--steps", str(STEPS), "--port", "0", "--data", str(tmp_path)], None
    )
    player = Player(server.url)
    try:
        player.enter_free_play()
        _round_page(player, 1)
        first = player.d.find_element(By.ID, "partner").text  # "Your partner: cec758m-s201 (cec). ..."
        assert "Your partner: cec" in first and "(cec)" in first
        player.click("round-start")
        _play(player, [3, 5, 2, 0, 5, 4])
        player.wait.until(EC.text_to_be_present_in_element((By.ID, "hint"), "Round over"))
        player.click("round-continue")  # "Play again"
        _round_page(player, 2)
        assert [r[0] for r in _summary_rows(player)] == ["1"]
        player.click("round-same")
        _play(player, [3, 5])
        player.d.refresh()  # a reload in the middle of round 2: round 2 afresh
        _round_page(player, 2)
        player.click("round-same")
        _play(player, [3, 5, 2, 0, 5, 4])
        player.click("round-continue")
        _round_page(player, 3)
        player.d.refresh()  # a reload between rounds: the fresh round 3 again, the summary kept
        _round_page(player, 3)
        assert [r[0] for r in _summary_rows(player)] == ["1", "2"]
        next_label = player.d.find_element(By.ID, "round-next").text  # "Next partner: cec758m-s202 (cec)"
        player.click("round-next")
        _play(player, [4] * STEPS)
        player.click("round-continue")
        _round_page(player, 4)
        rows = _summary_rows(player)
    finally:
        player.close()
        code = server.stop(signal.SIGINT)
    assert code == 0 and "Traceback" not in server.log, server.log
    assert [r[0] for r in rows] == ["1", "2", "3"] and rows[0][1] == rows[1][1] != rows[2][1]
    assert next_label == f"Next partner: {rows[2][1]} ({rows[2][2]})"
    assert server.study.startswith("free_play-cec-cramped_room-")
    files = FileStore(tmp_path, server.study)
    try:
        ((pid,),) = [files.participants()]
        events = files.events(pid)
    finally:
        files.close()
    rounds = finished_rounds(pid, events)
    assert [(r.round, r.start["attempt"], len(r.steps)) for r in rounds] == [
        (0, 0, STEPS),
        (1, 1, STEPS),
        (2, 0, STEPS),
    ]
    assert [r.start["policy"] for r in rounds] == [row[1] for row in rows]
    aborts = [(ev["round"], ev["attempt"]) for ev in events if ev["type"] == "round_abort"]
    assert aborts == [(1, 0)]  # the reload in round 2; the reload between rounds left nothing to abort
    assert [int(row[3]) for row in rows] == [int(r.end["return"]) for r in rounds]


@pytest.mark.parametrize("gives_way_after", [0, 3])
def test_the_page_says_to_step_aside_after_bumping_head_on(tmp_path: Path, gives_way_after: int) -> None:
    """The agent is in a dead end (no free cell to give way onto): the hint comes after 3 bumps, or 3 more
    than the agent's own `agent_gives_way_after`, and says which."""
    _browser_paths()
    (tmp_path / "head_on.txt").write_text(HEAD_ON)
    (tmp_path / "study.yaml").write_text(
        "name: head_on\nfree_play: true\nlevels: [head_on.txt]\nhuman_seat: 0\nagent_actions: sampled\n"
        f"agent_gives_way_after: {gives_way_after}\n"
        "partners: [{name: random, random_init: true}]\nsurvey: {items: []}\n"
        "env: {max_steps: 12, random_start_facing: false}\n"
        f"storage: {{dir: {tmp_path / 'records'}}}\n"
    )
    server = PlayServer([str(tmp_path / "study.yaml"), "--port", "0"], "head_on")
    player = Player(server.url)
    try:
        player.enter_free_play()
        _round_page(player, 1)
        player.click("round-start")
        player.wait.until(EC.presence_of_element_located((By.ID, "board")))
        hint = player.d.find_element(By.ID, "bump-hint")
        shown = []
        for i in range(5 + gives_way_after):  # east, into the agent's cell: a collision every step
            player.turn(i, 2)
            shown.append(hint.is_displayed())
        text = hint.text
        stats = player.stats()
    finally:
        player.close()
        server.stop(signal.SIGINT)
    assert shown == [False] * (2 + gives_way_after) + [True] * 3, shown
    assert text == (
        f"You have bumped into each other {3 + gives_way_after} times in a row. Your partner has no free "
        "cell beside it to step onto. Step aside into a free cell and let it pass."
    ), text
    assert stats["bumpHints"] == 1 and stats["standoffHints"] == 0
    files = FileStore(tmp_path / "records", "head_on")
    try:
        ((pid,),) = [files.participants()]
        steps = [ev for ev in files.events(pid) if ev["type"] == "step"]
    finally:
        files.close()
    # the block the page saw is in the records
    assert [s["collision"] for s in steps[: 5 + gives_way_after]] == [True] * (5 + gives_way_after)


def test_a_standoff_without_bumps_and_a_bump_beside_a_free_cell_are_hinted_as_the_board_shows(
    tmp_path: Path,
) -> None:
    """A person who stands in the pot's only access cell (STANDOFF) while the agent waits: no bump, and after
    5 steps the page says who stands in whose way, to what; it goes when the person moves. Then the person
    walks into the agent, which has a free cell beside it: the bump hint says so (it said "found no free
    cell" whatever the board showed). The agent is a random network that always waits (greedy, init seed
    5; the records show that it did)."""
    _browser_paths()
    (tmp_path / "standoff.txt").write_text(STANDOFF)
    (tmp_path / "study.yaml").write_text(
        "name: standoff\nfree_play: true\nlevels: [standoff.txt]\nhuman_seat: 0\nagent_actions: greedy\n"
        "agent_gives_way_after: 0\npartners: [{name: waits, random_init: true, init_seed: 5}]\n"
        "survey: {items: []}\nenv: {max_steps: 14, random_start_facing: false}\n"
        f"storage: {{dir: {tmp_path / 'records'}}}\n"
    )
    server = PlayServer([str(tmp_path / "study.yaml"), "--port", "0"], "standoff")
    player = Player(server.url)
    actions = [4] * 5 + [3, 2] + [2] * 3  # wait 5 steps; step west and back; walk east into the agent 3 times
    try:
        player.enter_free_play()
        _round_page(player, 1)
        player.click("round-start")
        player.wait.until(EC.presence_of_element_located((By.ID, "board")))
        standoff, bump = (player.d.find_element(By.ID, name) for name in ("standoff-hint", "bump-hint"))
        seen = []
        for i, action in enumerate(actions):
            player.turn(i, action)
            seen.append((standoff.is_displayed(), bump.is_displayed()))
            if i == 4:
                standoff_text = standoff.text
        bump_text = bump.text
        stats = player.stats()
    finally:
        player.close()
        server.stop(signal.SIGINT)
    files = FileStore(tmp_path / "records", "standoff")
    try:
        ((pid,),) = [files.participants()]
        steps = [ev for ev in files.events(pid) if ev["type"] == "step"]
    finally:
        files.close()
    # what was staged: the agent waited in its cell, and only the walks into it were bumps
    assert [s["actions"][1] for s in steps] == [4] * len(actions), [s["actions"] for s in steps]
    assert {tuple(s["state"]["pos"][1]) for s in steps} == {(1, 4)}
    assert [s["collision"] for s in steps] == [False] * 7 + [True] * 3
    assert seen == [(False, False)] * 4 + [(True, False)] + [(False, False)] * 4 + [(False, True)], seen
    assert standoff_text == (
        "Neither of you has moved for 5 steps: you are standing in your partner's only way to the pot, the "
        "onions and the plates. Step aside and let it pass. It stands in your only way to the serving window."
    ), standoff_text
    assert bump_text == (
        "You have bumped into each other 3 times in a row. Your partner has a free cell beside it but does "
        "not give way. Step aside into a free cell and let it pass."
    ), bump_text
    assert stats["standoffHints"] == 1 and stats["bumpHints"] == 1
