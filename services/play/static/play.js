// cec play: the study page. The server says which stage to show (/api/state); rounds run over /ws/round.
// Turn-based rounds draw the precomputed next state the moment a key goes down (the server sends the six
// states the six actions lead to); real-time rounds draw each tick's state as it arrives.
"use strict";

const KEYS = {
  ArrowUp: 0, w: 0, W: 0,
  ArrowDown: 1, s: 1, S: 1,
  ArrowRight: 2, d: 2, D: 2,
  ArrowLeft: 3, a: 3, A: 3,
  x: 4, X: 4,
  " ": 5, e: 5, E: 5,
};
const TILE = { FLOOR: 0, COUNTER: 1, ONION_PILE: 2, PLATE_PILE: 3, POT: 4, GOAL: 5 };
const ITEM = { NONE: 0, ONION: 1, PLATE: 2, DISH: 3 };
const DIRS = [[-1, 0], [1, 0], [0, 1], [0, -1]]; // N S E W as (d_row, d_col)
const POT_EMPTY = 23, POT_FULL = 20, POT_READY = 0;
const COLORS = {
  floor: "rgb(238,232,218)", floorLine: "rgb(220,212,194)",
  counter: "rgb(168,128,88)", counterEdge: "rgb(116,84,54)",
  onion: "rgb(242,200,44)", onionEdge: "rgb(160,112,16)",
  plate: "rgb(252,252,252)", plateEdge: "rgb(128,128,128)",
  soup: "rgb(236,118,28)", soupEdge: "rgb(170,74,12)",
  pot: "rgb(52,52,58)", potRim: "rgb(112,112,122)", bar: "rgb(40,28,20)", ready: "rgb(60,220,90)",
  goal: "rgb(62,160,72)", goalInner: "rgb(138,212,138)",
  agent: ["rgb(52,104,224)", "rgb(214,58,48)"], agentDark: ["rgb(22,48,128)", "rgb(120,24,18)"],
};
const SEAT_NAMES = ["blue", "red"];
// Free play: after this many bumps in a row the page says to step aside (this many more than the agent's own
// `gives_way_after`, where it steps aside itself), and the hint goes after this many steps without one.
const BUMP_HINT = 3, BUMP_CLEAR = 4;
// Free play: a standoff is this many steps (turn-based), or seconds (real time), in which neither cook moved,
// picked up or put down anything, or bumped, while one stands in the other's only way to a station.
const STANDOFF_STEPS = 5, STANDOFF_S = 3;
const STATIONS = [[TILE.POT, "the pot"], [TILE.ONION_PILE, "the onions"], [TILE.PLATE_PILE, "the plates"],
  [TILE.GOAL, "the serving window"]];

// Measurements of the current round a test or a researcher can read: key-down to painted frame, key-down to
// server reply (ms), frames drawn; `lastState` is the compact state on screen.
function resetStats(mode) {
  window.cecStats = { keyToFrame: [], roundTrip: [], frames: 0, mode, lastState: null, bumpHints: 0, standoffHints: 0 };
}
resetStats(null);

const app = document.getElementById("app");

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v;
    else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return node;
}

function paragraphs(text) {
  return String(text || "").split(/\n\s*\n/).filter((p) => p.trim()).map((p) => el("p", {}, p.trim()));
}

async function api(path, body) {
  const init = body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  };
  const res = await fetch(path, { credentials: "same-origin", ...init });
  const data = await res.json();
  if (!res.ok) throw new Error(data.error || res.statusText);
  return data;
}

function show(...nodes) {
  app.replaceChildren(...nodes);
}

function errorLine() {
  return el("p", { class: "error", id: "error" });
}

async function act(request, errorNode) {
  try {
    render(await request());
  } catch (err) {
    (errorNode || document.getElementById("error")).textContent = err.message;
  }
}

async function refresh() {
  try {
    render(await api("/api/state"));
  } catch (err) {
    show(el("p", { class: "error" }, "Cannot reach the study server: " + err.message));
  }
}

function render(view) {
  document.title = view.title || document.title;
  const stage = view.stage;
  app.dataset.stage = stage;
  if (stage === "welcome") {
    const err = errorLine();
    show(el("h1", {}, view.title), el("p", {}, "Welcome! Press Start to begin."),
      el("div", { class: "row" }, el("button", { id: "start", onclick: () => act(() => api("/api/join", {}), err) }, "Start")), err);
  } else if (stage === "consent") {
    const err = errorLine();
    const send = (accept) => act(() => api("/api/submit", { stage: "consent", accept }), err);
    show(el("h1", {}, "Consent"), el("div", { class: "card" }, ...paragraphs(view.text)),
      el("div", { class: "row" },
        el("button", { id: "consent-accept", onclick: () => send(true) }, "I agree"),
        el("button", { id: "consent-decline", class: "secondary", onclick: () => send(false) }, "I do not agree")),
      err);
  } else if (stage === "info") {
    const err = errorLine();
    const inputs = view.fields.map((f) => el("input", { id: "info-" + f.id, maxlength: String(f.max_length), autocomplete: "off" }));
    const form = el("div", { class: "card" }, ...view.fields.map((f, i) => el("label", { class: "field" }, f.label, inputs[i])));
    const submit = () => {
      const fields = {};
      view.fields.forEach((f, i) => { fields[f.id] = inputs[i].value; });
      act(() => api("/api/submit", { stage: "info", fields }), err);
    };
    show(el("h1", {}, "About you"), form, el("div", { class: "row" }, el("button", { id: "info-submit", onclick: submit }, "Continue")), err);
  } else if (stage === "instructions") {
    const err = errorLine();
    const keys = el("table", { class: "keys" },
      el("tr", {}, el("td", {}, el("kbd", {}, "←"), " ", el("kbd", {}, "↑"), " ", el("kbd", {}, "→"), " ", el("kbd", {}, "↓"), "  or  ",
        el("kbd", {}, "W"), " ", el("kbd", {}, "A"), " ", el("kbd", {}, "S"), " ", el("kbd", {}, "D")), el("td", {}, "move / turn")),
      el("tr", {}, el("td", {}, el("kbd", {}, "Space"), " or ", el("kbd", {}, "E")), el("td", {}, "pick up, put down, use a pot or the serving window")),
      el("tr", {}, el("td", {}, el("kbd", {}, "X")), el("td", {}, "wait one step")));
    const next = view.free_play ? "Play as many rounds as you like; after each one you choose who you cook with next."
      : view.practice ? "Start with a practice round." : `You will play ${view.rounds} round(s).`;
    show(el("h1", {}, "Instructions"), el("div", { class: "card" }, ...paragraphs(view.text), el("h2", {}, "Controls"), keys),
      el("p", {}, next),
      el("div", { class: "row" }, el("button", { id: "instructions-continue", onclick: () => act(() => api("/api/submit", { stage: "instructions" }), err) }, "Continue")),
      err);
  } else if (stage === "round") {
    showRound(view);
  } else if (stage === "survey") {
    showSurvey(view);
  } else if (stage === "done") {
    show(el("h1", {}, "Thank you!"), el("p", {}, "You have finished the study. Your completion code:"),
      el("p", {}, el("span", { class: "code", id: "completion-code" }, view.code)));
  } else if (stage === "capped") {
    show(el("h1", {}, "Thank you!"), el("p", { id: "capped" }, view.text));
  } else if (stage === "declined") {
    show(el("h1", {}, "Thank you"), el("p", {}, "You did not give consent, so the study ends here. You may close this page."));
  } else {
    show(el("p", { class: "error" }, "Unknown stage " + stage));
  }
}

function showSurvey(view) {
  const err = errorLine();
  const items = view.items.map((item) => {
    const options = view.scale.map((label, i) => el("label", { for: `q-${item.id}-${i + 1}` },
      el("input", { type: "radio", name: item.id, value: String(i + 1), id: `q-${item.id}-${i + 1}` }), label));
    return el("div", { class: "survey-item" }, el("div", {}, item.text), el("div", { class: "scale" }, ...options));
  });
  const submit = () => {
    const answers = {};
    for (const item of view.items) {
      const checked = document.querySelector(`input[name="${item.id}"]:checked`);
      if (checked) answers[item.id] = Number(checked.value);
    }
    if (Object.keys(answers).length !== view.items.length) {
      err.textContent = "Please answer every statement.";
      return;
    }
    act(() => api("/api/submit", { stage: "survey", round: view.number - 1, answers }), err);
  };
  show(el("h1", {}, `About partner ${view.number}`), el("p", {}, view.prompt), el("div", { class: "card" }, ...items),
    el("div", { class: "row" }, el("button", { id: "survey-submit", onclick: submit }, "Submit")), err);
}

// --- the round ----------------------------------------------------------------------------------------

// Free play: the person's rounds so far, latest last.
function summary(view) {
  if (!view.played || !view.played.length) return [];
  const head = el("tr", {}, ...["Round", "Partner", "Kind", "Score", "Soups", "Bumps"].map((h) => el("th", {}, h)));
  const rows = view.played.map((r) => el("tr", {}, el("td", {}, r.number), el("td", {}, r.partner), el("td", {}, r.kind),
    el("td", {}, r.score), el("td", {}, r.deliveries), el("td", {}, r.collisions)));
  const total = view.played.reduce((a, r) => a + r.score, 0);
  const shown = view.played.length < view.rounds_played ? ` (the latest ${view.played.length} shown)` : "";
  return [el("h2", {}, "Your rounds so far"), el("table", { class: "summary", id: "summary" }, head, ...rows),
    el("p", { class: "muted" }, `${view.rounds_played} round(s), total score ${total}${shown}.`)];
}

function showFreeRound(view) {
  const pace = view.mode === "turn_based"
    ? "The game moves one step each time you press a key."
    : `The game runs by itself at ${view.ticks_per_second} steps per second; your partner keeps moving.`;
  const err = errorLine();
  const play = (choice) => async (e) => {
    for (const b of document.querySelectorAll(".row button")) b.disabled = true;
    try {
      const next = choice ? await api("/api/submit", { stage: "round", round: view.number - 1, partner: choice }) : view;
      new Game(next, err).connect();
    } catch (ex) {
      err.textContent = ex.message;
      for (const b of document.querySelectorAll(".row button")) b.disabled = false;
    }
  };
  const buttons = [];
  if (!view.same) {
    buttons.push(el("button", { id: "round-start", onclick: play(null) }, "Start round"));
  } else {
    buttons.push(el("button", { id: "round-same", onclick: play("same") }, `Play again with ${view.same.name}`));
    if (view.next.name !== view.same.name) {
      buttons.push(el("button", { id: "round-next", class: "secondary", onclick: play("next") }, `Next partner: ${view.next.name} (${view.next.kind})`));
    }
  }
  show(el("h1", {}, `Round ${view.number}`),
    el("p", { id: "partner" }, `Your partner: ${view.partner_label}.${view.partner_note ? ` ${view.partner_note}.` : ""} ${pace}`), ...summary(view),
    el("div", { class: "row" }, ...buttons), err);
}

function showRound(view) {
  if (view.free_play) return showFreeRound(view);
  const heading = view.practice ? "Practice round" : `Round ${view.number} of ${view.of}`;
  const sub = view.practice ? "Get to know the kitchen and the controls." : `You are playing with ${view.partner_label}.`;
  const pace = view.mode === "turn_based"
    ? "The game moves one step each time you press a key."
    : `The game runs by itself at ${view.ticks_per_second} steps per second; your partner keeps moving.`;
  const start = el("button", { id: "round-start" }, "Start round");
  const err = errorLine();
  show(el("h1", {}, heading), el("p", {}, sub + " " + pace), el("div", { class: "row" }, start), err);
  start.addEventListener("click", () => {
    start.disabled = true;
    new Game(view, err).connect();
  });
}

class Game {
  constructor(view, errorNode) {
    this.view = view;
    this.err = errorNode;
    this.branches = null; // turn-based: the six next states, or null while waiting for the server
    this.queued = null; // turn-based: a key pressed while waiting
    this.t = 0;
    this.score = 0;
    this.seq = 0;
    this.keyTimes = new Map(); // real-time: seq -> key-down time
    this.frameShownAt = 0;
    this.sentAt = 0;
    this.over = false;
    this.bumps = 0; // collisions in a row (free play's step-aside hint)
    this.calm = 0; // steps without one since the hint was shown
    this.still = 0; // steps in a row in which no cook moved, picked up or put down anything, or bumped
    this.last = null; // the state of the last frame (what the hints compare with)
    this.onKey = this.onKey.bind(this);
  }

  connect() {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    this.ws = new WebSocket(`${scheme}://${location.host}/ws/round`);
    this.ws.onmessage = (e) => this.onMessage(JSON.parse(e.data));
    this.ws.onclose = () => {
      document.removeEventListener("keydown", this.onKey);
      if (!this.over) this.err.textContent = "The connection closed. Reload the page to play this round again.";
    };
  }

  onMessage(msg) {
    if (msg.type === "start") {
      this.start(msg);
    } else if (msg.type === "frame") {
      this.frame(msg);
    } else if (msg.type === "end") {
      this.end(msg);
    } else if (msg.type === "error") {
      this.err.textContent = msg.message;
      if (msg.capped) { this.over = true; refresh(); } // past a cap of the server's limits: its page says why
    }
  }

  start(msg) {
    this.level = msg.level;
    this.seat = msg.human_seat;
    this.mode = msg.mode;
    this.steps = msg.steps;
    this.tps = msg.ticks_per_second;
    resetStats(msg.mode);
    const size = Math.max(40, Math.min(72, Math.floor(600 / Math.max(this.level.w, this.level.h))));
    this.tile = size;
    this.canvas = el("canvas", { id: "board", width: String(this.level.w * size), height: String(this.level.h * size) });
    this.ctx = this.canvas.getContext("2d");
    this.hudScore = el("span", { id: "score" });
    this.hudTime = el("span", { id: "time-left" });
    const you = el("span", { class: "you-" + this.seat }, `You are the ${SEAT_NAMES[this.seat]} chef`);
    const heading = msg.practice ? "Practice round"
      : this.view.free_play ? `Round ${this.view.number} · with ${this.view.partner_label}`
        : `Round ${this.view.number} of ${this.view.of} · ${this.view.partner_label}`;
    this.bumpHint = el("p", { class: "bump-hint", id: "bump-hint", hidden: "" });
    this.standoffHint = el("p", { class: "bump-hint", id: "standoff-hint", hidden: "" });
    this.standoffAfter = this.mode === "real_time" ? Math.max(STANDOFF_STEPS, Math.round(STANDOFF_S * this.tps)) : STANDOFF_STEPS;
    show(el("h1", {}, heading), el("div", { class: "game" }, el("div", { class: "hud" }, you, this.hudScore, this.hudTime), this.canvas,
      this.bumpHint, this.standoffHint,
      el("p", { class: "muted", id: "hint" }, this.mode === "turn_based" ? "Press a key to move; the game waits for you." : "Go!")), this.err);
    this.draw(msg.state);
    this.last = msg.state;
    this.branches = msg.branches || null;
    document.addEventListener("keydown", this.onKey);
  }

  onKey(e) {
    if (this.over || e.ctrlKey || e.metaKey || e.altKey || !(e.key in KEYS)) return;
    e.preventDefault();
    if (e.repeat && this.mode === "turn_based") return; // a held key is one move per press
    const action = KEYS[e.key];
    const keyTime = e.timeStamp || performance.now();
    if (this.mode === "turn_based") {
      if (this.branches) this.play(action, keyTime);
      else if (!this.queued) this.queued = { action, keyTime };
    } else {
      this.seq += 1;
      this.keyTimes.set(this.seq, keyTime);
      this.ws.send(JSON.stringify({ type: "key", seq: this.seq, action, rt_ms: Math.max(0, keyTime - this.frameShownAt) }));
    }
  }

  play(action, keyTime) {
    const next = this.branches[action];
    this.branches = null;
    this.draw(next, keyTime);
    this.ws.send(JSON.stringify({ type: "act", t: this.t, action, rt_ms: Math.max(0, keyTime - this.frameShownAt) }));
    this.sentAt = keyTime;
    this.t += 1;
  }

  // Free play: bumped BUMP_HINT (+ the agent's gives_way_after) times in a row -> say to step aside, and whether
  // the partner has a free cell beside it, read from the board shown; gone after BUMP_CLEAR calm steps.
  bumped(collision, state) {
    if (!this.view.free_play) return;
    this.bumps = collision ? this.bumps + 1 : 0;
    this.calm = collision ? 0 : this.calm + 1;
    const yields = this.view.gives_way_after || 0;
    if (this.bumps >= BUMP_HINT + yields && this.bumpHint.hidden) {
      // bumps move no one, so a partner with a free cell beside it did not step onto it
      const partner = freeCells(this.level, state, 1 - this.seat) === 0 ? "Your partner has no free cell beside it to step onto."
        : yields ? "Your partner has a free cell beside it but has not stepped aside."
          : "Your partner has a free cell beside it but does not give way.";
      const you = freeCells(this.level, state, this.seat) > 0 ? "Step aside into a free cell and let it pass."
        : "You have no free cell beside you either: wait (X) and let it move.";
      this.bumpHint.textContent = `You have bumped into each other ${this.bumps} times in a row. ${partner} ${you}`;
      this.bumpHint.hidden = false;
      window.cecStats.bumpHints += 1;
    } else if (this.calm >= BUMP_CLEAR) {
      this.bumpHint.hidden = true;
    }
  }

  // Free play: neither cook moved, picked up or put down anything, or bumped for `standoffAfter` steps while one
  // stands in the other's only way to a station (read from the board shown) -> say who blocks whom; gone at the
  // next move or hand change.
  stoodStill(collision, state) {
    if (!this.view.free_play) return;
    const same = this.last && JSON.stringify([state.pos, state.inv]) === JSON.stringify([this.last.pos, this.last.inv]);
    this.last = state;
    this.still = same && !collision ? this.still + 1 : 0;
    if (!same) this.standoffHint.hidden = true;
    if (this.still < this.standoffAfter || !this.standoffHint.hidden) return;
    const text = this.standoffText(state);
    if (!text) return;
    this.standoffHint.textContent = text;
    this.standoffHint.hidden = false;
    window.cecStats.standoffHints += 1;
  }

  standoffText(state) {
    const theirs = cutOff(this.level, state, 1 - this.seat), yours = cutOff(this.level, state, this.seat);
    const lead = "Neither of you has moved for " +
      (this.mode === "real_time" ? `${Math.round(this.still / this.tps)} seconds` : `${this.still} steps`);
    if (theirs.length) {
      const also = yours.length ? ` It stands in your only way to ${names(yours)}.` : "";
      return `${lead}: you are standing in your partner's only way to ${names(theirs)}. Step aside and let it pass.${also}`;
    }
    if (!yours.length) return "";
    const yields = this.view.gives_way_after || 0;
    const way = yields ? ` It steps aside after ${yields} bumps in a row, if it has a free cell beside it.` : " It does not give way.";
    return `${lead}: your partner is standing in your only way to ${names(yours)}.${way}`;
  }

  frame(msg) {
    this.score = msg.score;
    this.bumped(msg.collision, msg.state);
    this.stoodStill(msg.collision, msg.state);
    if (this.mode === "turn_based") {
      window.cecStats.roundTrip.push(performance.now() - this.sentAt);
      if (JSON.stringify(msg.state) !== JSON.stringify(this.shown)) this.draw(msg.state); // never differs in practice
      else this.updateHud(msg.state);
      this.t = msg.t;
      this.branches = msg.done ? null : msg.branches;
      if (msg.done) this.finish();
      else if (this.queued) {
        const q = this.queued;
        this.queued = null;
        this.play(q.action, q.keyTime);
      }
    } else {
      const keyTime = msg.ack != null ? this.keyTimes.get(msg.ack) : undefined;
      if (msg.ack != null) this.keyTimes.delete(msg.ack);
      this.t = msg.t;
      this.draw(msg.state, keyTime);
      if (msg.done) this.finish();
    }
  }

  finish() {
    this.over = true;
    document.removeEventListener("keydown", this.onKey);
  }

  end(msg) {
    this.over = true;
    const cont = el("button", { id: "round-continue", onclick: () => refresh() }, this.view.free_play ? "Play again" : "Continue");
    const hint = document.getElementById("hint");
    hint.textContent = `Round over. Team score: ${msg.return}.`;
    hint.after(el("div", { class: "row" }, cont));
    cont.focus();
  }

  updateHud(state) {
    this.hudScore.textContent = `Score: ${this.score}`;
    const left = this.steps - state.t;
    this.hudTime.textContent = this.mode === "turn_based" ? `Steps left: ${left}` : `Time left: ${(left / this.tps).toFixed(1)} s`;
  }

  // Draws a compact state; with `keyTime`, records key-down to the paint of this frame.
  draw(state, keyTime) {
    this.shown = state;
    window.cecStats.lastState = state;
    drawKitchen(this.ctx, this.level, state, this.tile, this.seat);
    this.updateHud(state);
    window.cecStats.frames += 1;
    requestAnimationFrame(() => {
      this.frameShownAt = performance.now();
      if (keyTime !== undefined) window.cecStats.keyToFrame.push(this.frameShownAt - keyTime);
    });
  }
}

// --- reading the board (free play's hints) ------------------------------------------------------------------

function tileAt(level, r, c) {
  return r >= 0 && c >= 0 && r < level.h && c < level.w ? level.grid[r][c] : TILE.COUNTER;
}

function at(pos, r, c) {
  return pos[0] === r && pos[1] === c;
}

// How many floor cells beside `seat` no cook stands on.
function freeCells(level, state, seat) {
  const [r, c] = state.pos[seat];
  return DIRS.filter(([dr, dc]) => tileAt(level, r + dr, c + dc) === TILE.FLOOR && !at(state.pos[1 - seat], r + dr, c + dc)).length;
}

// The tiles next to the floor cells a cook at `start` can walk to, `closed` (a cell or null) closed off.
function reachableTiles(level, start, closed) {
  const seen = new Set([start[0] * 16 + start[1]]), todo = [start], tiles = new Set();
  while (todo.length) {
    const [r, c] = todo.pop();
    for (const [dr, dc] of DIRS) {
      const nr = r + dr, nc = c + dc, tile = tileAt(level, nr, nc);
      if (tile !== TILE.FLOOR) tiles.add(tile);
      else if (!seen.has(nr * 16 + nc) && !(closed && at(closed, nr, nc))) {
        seen.add(nr * 16 + nc);
        todo.push([nr, nc]);
      }
    }
  }
  return tiles;
}

// The stations `seat` can reach only through the cell its partner stands on.
function cutOff(level, state, seat) {
  const open = reachableTiles(level, state.pos[seat], null), shut = reachableTiles(level, state.pos[seat], state.pos[1 - seat]);
  return STATIONS.filter(([tile]) => open.has(tile) && !shut.has(tile)).map(([, name]) => name);
}

function names(list) {
  return list.length > 1 ? `${list.slice(0, -1).join(", ")} and ${list[list.length - 1]}` : list[0];
}

// --- drawing (the palette of cec.envs.overcooked.render) --------------------------------------------------

function drawKitchen(ctx, level, state, s, humanSeat) {
  const items = new Map(state.items.map(([r, c, it]) => [r * 16 + c, it]));
  const pots = new Map(state.pots.map(([r, c, st]) => [r * 16 + c, st]));
  for (let r = 0; r < level.h; r++) {
    for (let c = 0; c < level.w; c++) {
      const x = c * s, y = r * s, tile = level.grid[r][c];
      drawTile(ctx, x, y, s, tile, pots.get(r * 16 + c));
      const item = items.get(r * 16 + c);
      if (item) drawItem(ctx, x + s / 2, y + s / 2, s, 1.0, item);
    }
  }
  for (let seat = 0; seat < 2; seat++) {
    const [r, c] = state.pos[seat];
    drawAgent(ctx, c * s, r * s, s, seat, state.dir[seat], state.inv[seat], seat === humanSeat);
  }
}

function rect(ctx, x, y, w, h, fill, stroke, lw, radius = 0) {
  ctx.beginPath();
  if (radius > 0 && ctx.roundRect) ctx.roundRect(x, y, w, h, radius);
  else ctx.rect(x, y, w, h);
  ctx.fillStyle = fill;
  ctx.fill();
  if (stroke) { ctx.lineWidth = lw || 1; ctx.strokeStyle = stroke; ctx.stroke(); }
}

function disc(ctx, x, y, rad, fill, stroke, lw) {
  ctx.beginPath();
  ctx.arc(x, y, rad, 0, 2 * Math.PI);
  ctx.fillStyle = fill;
  ctx.fill();
  if (stroke) { ctx.lineWidth = lw || 1; ctx.strokeStyle = stroke; ctx.stroke(); }
}

function drawTile(ctx, x, y, s, tile, potStatus) {
  const lw = Math.max(1, s / 24);
  if (tile === TILE.FLOOR) {
    rect(ctx, x, y, s, s, COLORS.floor, COLORS.floorLine, lw / 2);
    return;
  }
  if (tile === TILE.GOAL) {
    rect(ctx, x, y, s, s, COLORS.goal, COLORS.counterEdge, lw);
    rect(ctx, x + 0.16 * s, y + 0.16 * s, 0.68 * s, 0.68 * s, COLORS.goalInner, COLORS.goal, 2 * lw, 0.08 * s);
    disc(ctx, x + s / 2, y + s / 2, 0.18 * s, COLORS.goalInner, "#fff", lw);
    return;
  }
  rect(ctx, x, y, s, s, COLORS.counter, COLORS.counterEdge, lw);
  if (tile === TILE.ONION_PILE) {
    for (const [fy, fx] of [[0.36, 0.32], [0.36, 0.68], [0.66, 0.5], [0.66, 0.2], [0.66, 0.8]]) {
      disc(ctx, x + fx * s, y + fy * s, 0.15 * s, COLORS.onion, COLORS.onionEdge, lw);
    }
  } else if (tile === TILE.PLATE_PILE) {
    for (let k = 0; k < 3; k++) disc(ctx, x + 0.5 * s, y + (0.62 - 0.08 * k) * s, 0.3 * s, COLORS.plate, COLORS.plateEdge, lw);
  } else if (tile === TILE.POT) {
    drawPot(ctx, x, y, s, potStatus === undefined ? POT_EMPTY : potStatus, lw);
  }
}

function drawPot(ctx, x, y, s, status, lw) {
  const ready = status === POT_READY;
  const cooking = status > POT_READY && status <= POT_FULL;
  if (ready) rect(ctx, x + 0.03 * s, y + 0.03 * s, 0.94 * s, 0.94 * s, COLORS.counter, COLORS.ready, 3 * lw);
  rect(ctx, x + 0.06 * s, y + 0.34 * s, 0.88 * s, 0.12 * s, COLORS.pot, null, 0, 0.05 * s);
  rect(ctx, x + 0.14 * s, y + 0.2 * s, 0.72 * s, 0.6 * s, COLORS.pot, COLORS.potRim, lw, 0.1 * s);
  if (ready) {
    rect(ctx, x + 0.22 * s, y + 0.27 * s, 0.56 * s, 0.25 * s, COLORS.soup, COLORS.soupEdge, lw, 0.08 * s);
  } else {
    const onions = Math.max(0, Math.min(3, POT_EMPTY - status));
    for (let k = 0; k < onions; k++) disc(ctx, x + (0.29 + 0.21 * k) * s, y + 0.38 * s, 0.085 * s, COLORS.onion, COLORS.onionEdge, lw);
  }
  if (cooking || ready) {
    const done = ready ? 1 : (POT_FULL - status) / POT_FULL;
    rect(ctx, x + 0.1 * s, y + 0.84 * s, 0.8 * s, 0.11 * s, COLORS.bar);
    if (done > 0) rect(ctx, x + 0.1 * s, y + 0.84 * s, 0.8 * done * s, 0.11 * s, ready ? COLORS.ready : COLORS.soup);
  }
}

function drawItem(ctx, cx, cy, s, scale, item) {
  const lw = Math.max(1, s / 24);
  if (item === ITEM.ONION) disc(ctx, cx, cy, 0.2 * scale * s, COLORS.onion, COLORS.onionEdge, lw);
  else if (item === ITEM.PLATE || item === ITEM.DISH) {
    disc(ctx, cx, cy, 0.27 * scale * s, COLORS.plate, COLORS.plateEdge, lw);
    if (item === ITEM.DISH) disc(ctx, cx, cy, 0.17 * scale * s, COLORS.soup, COLORS.soupEdge, lw);
  }
}

function drawAgent(ctx, x, y, s, seat, facing, held, isHuman) {
  const [dr, dc] = DIRS[facing % 4];
  const pr = -dc, pc = dr;
  const at = (along, across) => [x + (0.5 + along * dc + across * pc) * s, y + (0.5 + along * dr + across * pr) * s];
  ctx.beginPath();
  for (const [i, p] of [at(0.47, 0), at(0.12, 0.24), at(0.12, -0.24)].entries()) {
    if (i === 0) ctx.moveTo(p[0], p[1]); else ctx.lineTo(p[0], p[1]);
  }
  ctx.closePath();
  ctx.fillStyle = COLORS.agentDark[seat];
  ctx.fill();
  const lw = Math.max(1, s / 24);
  disc(ctx, x + 0.5 * s, y + 0.5 * s, 0.32 * s, COLORS.agent[seat], COLORS.agentDark[seat], isHuman ? 3 * lw : lw);
  for (const side of [0.12, -0.12]) {
    const [ex, ey] = at(0.17, side);
    disc(ctx, ex, ey, 0.055 * s, "#fff");
  }
  if (held) {
    const [hx, hy] = at(-0.07, 0);
    drawItem(ctx, hx, hy, s, 0.62, held);
  }
  if (isHuman) {
    ctx.font = `bold ${Math.round(0.2 * s)}px system-ui, sans-serif`;
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    ctx.lineWidth = 3;
    ctx.strokeStyle = "#fff";
    ctx.strokeText("YOU", x + 0.5 * s, y + 0.02 * s);
    ctx.fillStyle = COLORS.agentDark[seat];
    ctx.fillText("YOU", x + 0.5 * s, y + 0.02 * s);
  }
}

refresh();
