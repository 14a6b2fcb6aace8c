"""The live map page: its command-line options (`WebOptions`, the `--web` of fly, agent and demo), the
address and token they give (`web_setup`), the page's HTML and the drawing script it shares with
`swarmctl replay`'s map.html (`DRAW_JS`, static/draw.js). swarmctl.mission.web serves them."""

from __future__ import annotations

import ipaddress
import secrets
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from swarmctl.errors import InputError

DRAW_JS = resources.files("swarmctl.mission").joinpath("static/draw.js").read_text(encoding="utf-8")
TOKEN_MIN_CHARS = 16  # a token file's token, at least (secrets.token_urlsafe(24) gives 32)
TOKEN_FILE_MAX_BYTES = 4096
POLL_MS = 250  # the page asks for the mission's state this often: 4 updates a second


@dataclass(frozen=True)
class WebOptions:
    """The live page's options (swarmctl.cli_options.options_from makes them)."""

    web: str | None = field(
        default=None,
        metadata=dict(
            help="Serve a live map page of the mission, with its controls (pause, resume, return home, end), "
            "at [HOST:]PORT; --web alone: 127.0.0.1 and a free port. The page's address, with its control "
            "token, is printed when the mission starts.",
            metavar="[HOST:]PORT",
        ),
    )
    web_token_file: str | None = field(
        default=None,
        metadata=dict(
            help="A file holding the page's control token (at least 16 characters); needed when HOST is not "
            "loopback. Default: a random token for this run.",
            metavar="FILE",
        ),
    )


WEB_FIELDS = ("web", "web_token_file")
WEB_OVERRIDES = {"web": {"is_flag": False, "flag_value": ""}}  # `--web` alone: loopback, a free port


@dataclass(frozen=True)
class WebSetup:
    """Where the page is served and the token its controls need."""

    host: str
    port: int  # 0: a free port, chosen when the server starts
    token: str

    @property
    def loopback(self) -> bool:
        return is_loopback(self.host)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def web_setup(options: WebOptions) -> WebSetup | None:
    """The address and token `--web` and `--web-token-file` give (None: no page); InputError for an
    address that is not [HOST:]PORT, for a HOST other than loopback without a token file, and for a
    token file that cannot be read or holds too short a token."""
    if options.web is None:
        if options.web_token_file is not None:
            raise InputError("--web-token-file: only --web reads it; add --web [HOST:]PORT")
        return None
    text = options.web.strip()
    host, _, port_text = text.rpartition(":") if ":" in text else ("", "", text)
    host = host.strip("[]") or "127.0.0.1"
    if not text:
        port_text = "0"
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535 or not host.isprintable():
        raise InputError(f"--web {options.web!r}: give [HOST:]PORT, e.g. 8080 or 127.0.0.1:8080 (0: a free port)")
    if options.web_token_file is None:
        if not is_loopback(host):
            raise InputError(
                f"--web {options.web}: a page on {host} is open to other machines; give its control token "
                "with --web-token-file FILE, or serve it on 127.0.0.1"
            )
        return WebSetup(host, int(port_text), secrets.token_urlsafe(24))
    return WebSetup(host, int(port_text), read_token(Path(options.web_token_file)))


def probe(setup: WebSetup) -> None:
    """Refuse, before anything is recorded or flies, an address that cannot be served (the port taken,
    the host not this machine's); the server binds it again when the mission starts."""
    import socket

    if setup.port == 0:
        return
    try:
        infos = socket.getaddrinfo(setup.host, setup.port, type=socket.SOCK_STREAM)
        with socket.socket(infos[0][0], socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(infos[0][4])
    except OSError as exc:
        raise InputError(
            f"--web {setup.host}:{setup.port}: cannot be served ({exc.strerror or exc}); give another port, "
            "or --web alone for a free one"
        ) from None


def read_token(path: Path) -> str:
    """The token in a token file: its one line, at least TOKEN_MIN_CHARS printable characters."""
    try:
        with path.open("rb") as f:
            raw = f.read(TOKEN_FILE_MAX_BYTES + 1)
    except OSError as exc:
        raise InputError(f"--web-token-file {path}: cannot be read ({exc.strerror or exc})") from None
    try:
        token = raw.decode("ascii").strip()
    except UnicodeDecodeError:
        token = ""
    if len(raw) > TOKEN_FILE_MAX_BYTES or len(token) < TOKEN_MIN_CHARS or not all(33 <= ord(c) < 127 for c in token):
        raise InputError(
            f"--web-token-file {path}: holds no token (one line of {TOKEN_MIN_CHARS} to {TOKEN_FILE_MAX_BYTES} "
            "printable characters without spaces)"
        )
    return token


# The head and the map's layout, shared with the replay's map.html (its side panel __SIDE__ px wide).
PAGE_HEAD = r"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<link rel="icon" href="data:,">
<title>__TITLE__</title>
<style>
html, body { margin: 0; height: 100%; font: 13px system-ui, sans-serif; color: #222; }
#app { display: flex; height: 100%; }
#map { flex: 1; position: relative; background: #f4f4f0; cursor: grab; }
#map canvas { position: absolute; left: 0; top: 0; }
#side { width: __SIDE__px; overflow-y: auto; border-left: 1px solid #ccc; padding: 10px; box-sizing: border-box; }
#side h1 { font-size: 15px; margin: 0 0 4px; }
.note { color: #666; font-size: 11px; margin: 2px 0 8px; }
"""

PAGE = (
    PAGE_HEAD.replace("__SIDE__", "420")
    + r"""#clock { font-weight: bold; font-size: 15px; margin: 6px 0; }
#banner { display: none; padding: 6px; margin: 6px 0; background: #fff3c4; border: 1px solid #d9b300;
  font-weight: bold; }
#controls { display: flex; gap: 6px; margin: 8px 0; flex-wrap: wrap; }
#controls button { padding: 4px 10px; }
#end { background: #b00; color: #fff; border: 1px solid #800; }
#message { color: #a00; font-size: 12px; min-height: 14px; }
table { border-collapse: collapse; width: 100%; font-size: 12px; }
td, th { text-align: left; padding: 2px 4px; border-bottom: 1px solid #eee; }
tr.selected { background: #e8f0ff; }
#targets td { white-space: nowrap; }
#targets button { padding: 1px 4px; margin-left: 2px; }
.sw { display: inline-block; width: 10px; height: 10px; border-radius: 5px; margin-right: 4px; }
label { display: block; margin: 3px 0; }
</style>
</head>
<body>
<div id="app">
  <div id="map"><canvas id="canvas"></canvas></div>
  <div id="side">
    <h1 id="title"></h1>
    <div class="note" id="subtitle"></div>
    <div id="clock"></div>
    <div id="progress"></div>
    <div class="note" id="finish"></div>
    <div id="banner"></div>
    <div id="controls">
      <button id="pause" type="button">Pause search</button>
      <button id="resume" type="button">Resume</button>
      <button id="end" type="button">End mission</button>
    </div>
    <div id="message"></div>
    <div class="note" id="access"></div>
    <label><input type="checkbox" id="show-tracks" checked> tracks</label>
    <label><input type="checkbox" id="show-grid" checked> grid lines</label>
    <div class="note" id="explored-note">blue cells: explored by the whole swarm (click a vehicle for its own)</div>
    <table id="vehicles"><thead><tr><th>vehicle</th><th>state</th><th>battery</th><th>link</th><th>mode</th>
      <th></th></tr></thead><tbody></tbody></table>
    <h1 style="margin-top: 10px">Targets found</h1>
    <table id="targets"><thead><tr><th>time</th><th>lat, lon</th><th>by</th><th></th></tr></thead>
      <tbody></tbody></table>
  </div>
</div>
<script src="draw.js"></script>
<script src="live.js"></script>
</body>
</html>
"""
)

LIVE_JS = r"""// The live page: the mission's fixed parts once (live/setup), its state every POLL_MS (live/state),
// drawn with the replay's renderer (draw.js); the controls POST with the token from the URL fragment.
"use strict";
(function () {
  const POLL_MS = __POLL_MS__;
  const token = new URLSearchParams(location.hash.slice(1)).get("token");
  const canvas = document.getElementById("canvas"), mapDiv = document.getElementById("map");
  let map = null, setup = null, last = null, selected = -1, armedEnd = 0, exploredImage = null, polling = true;
  let haveTracks = false;  // the first answer brings each vehicle's track so far: a late page catches up
  const tracks = [];

  function colour(i, n) { return "hsl(" + Math.round(360 * i / Math.max(n, 1)) + ", 75%, 45%)"; }
  function text(id, value) { document.getElementById(id).textContent = value; }
  function clock(s) {
    const m = Math.floor(s / 60), r = s - 60 * m;
    return m + ":" + (r < 10 ? "0" : "") + r.toFixed(1);
  }

  async function send(body) {
    if (!token) return;
    try {
      const r = await fetch("control", {
        method: "POST", headers: { "Content-Type": "application/json", "X-Swarmctl-Token": token },
        body: JSON.stringify(body),
      });
      const answer = await r.json().catch(function () { return {}; });
      text("message", r.ok ? "" : (answer.error || ("refused: " + r.status)));
    } catch (e) {
      text("message", "the controller did not answer");
    }
  }

  function build(s) {
    setup = s;
    text("title", s.name);
    text("subtitle", s.subtitle);
    text("finish", s.finish);
    text("access", token ? "controls on (this page's address carries the control token)"
                         : "read-only: open the address with the control token printed in the terminal");
    if (!token) ["pause", "resume", "end"].forEach(function (id) { document.getElementById(id).disabled = true; });
    map = window.SwarmMap(canvas, mapDiv, s.grid);
    const tbody = document.querySelector("#vehicles tbody");
    s.vehicles.forEach(function (name, i) {
      tracks.push([]);
      const tr = document.createElement("tr");
      tr.innerHTML = "<td><span class='sw'></span></td><td></td><td></td><td></td><td></td><td></td>";
      tr.querySelector(".sw").style.background = colour(i, s.vehicles.length);
      tr.firstChild.appendChild(document.createTextNode(name));
      tr.addEventListener("click", function () { choose(selected === i ? -1 : i); });
      if (token) {
        const b = document.createElement("button");
        b.type = "button"; b.textContent = "home"; b.className = "home";
        b.addEventListener("click", function (e) { e.stopPropagation(); send({ action: "home", vehicle: name }); });
        tr.lastChild.appendChild(b);
      }
      tbody.appendChild(tr);
    });
    window.addEventListener("resize", function () { map.resize(); });
    mapDiv.addEventListener("click", function (e) {
      if (map.dragged()) return;
      const r = mapDiv.getBoundingClientRect(), i = map.markerAt(e.clientX - r.left, e.clientY - r.top);
      if (i >= 0) choose(selected === i ? -1 : i);
    });
    map.draw(scene());
    map.resize();
  }

  function choose(i) {
    selected = i;
    text("explored-note", i < 0 ? "blue cells: explored by the whole swarm (click a vehicle for its own)"
                                : "blue cells: explored by " + setup.vehicles[i] + " (click it again for the swarm's)");
    const rows = document.querySelector("#vehicles tbody").children;
    for (let k = 0; k < rows.length; k++) rows[k].className = k === i ? "selected" : "";
    poll(false);
  }

  function scene() {
    const n = setup.vehicles.length;
    const vs = setup.vehicles.map(function (name, i) {
      const v = last ? last.vehicles[i] : null;
      return { name: name, colour: colour(i, n), lat: v ? v.lat : null, lon: v ? v.lon : null,
               track: tracks[i], selected: i === selected };
    });
    return {
      area: setup.area, nofly: setup.nofly, buildings: [], basemap: null, explored: exploredImage,
      showGrid: document.getElementById("show-grid").checked,
      showTracks: document.getElementById("show-tracks").checked,
      vehicles: vs, hover: [], hidden: [],
      targets: last ? last.finds.map(function (f) {
        return { lat: f.lat, lon: f.lon, found: f.judged !== "rejected" };  // a rejected find: grey
      }) : [],
    };
  }

  function show(s) {
    last = s;
    s.vehicles.forEach(function (v, i) {
      const t = tracks[i];
      if (v.track) { tracks[i] = v.track; return; }
      if (v.lat === null) return;
      const p = t[t.length - 1];
      if (!p || p[0] !== v.lon || p[1] !== v.lat) t.push([v.lon, v.lat]);
    });
    const mask = map.bits(s.explored, setup.grid.w * setup.grid.h);
    exploredImage = map.cellImage(function (i) { return mask[i]; }, [40, 110, 220, 110]);
    const rows = document.querySelector("#vehicles tbody").children;
    s.vehicles.forEach(function (v, i) {
      const c = rows[i].children;
      c[1].textContent = v.state + (v.cell ? " " + v.cell.join(",") : "");
      c[2].textContent = v.battery === null ? "-" : v.battery + " %";
      c[3].textContent = v.link; c[4].textContent = v.mode;
      const b = c[5].querySelector("button");
      if (b) b.disabled = !v.can_go_home || s.ended;
    });
    text("clock", (s.paused ? "PAUSED  " : "") + "search " + clock(s.clock) + " of " + clock(setup.time_limit) +
         "   step " + s.step);
    const found = s.finds.filter(function (f) { return f.judged !== "rejected"; }).length;
    text("progress", s.covered[0] + " of " + s.covered[1] + " cells covered; " + found +
         " target" + (found === 1 ? "" : "s") + " found" +
         (setup.expected === null ? "" : " of " + setup.expected) + "; " + s.explored_count + " cells explored" +
         (selected >= 0 ? " by " + setup.vehicles[selected] : "") +
         (s.pos === undefined ? "" : "; POS " + s.pos.toFixed(3) + (s.pos_goal ? " of " + s.pos_goal : "") +
          ", probability left " + (1 - s.pos).toFixed(3)));
    const tb = document.querySelector("#targets tbody");
    while (tb.children.length < s.finds.length) {
      const f = s.finds[tb.children.length], tr = document.createElement("tr");
      tr.innerHTML = "<td></td><td></td><td></td><td><span></span></td>";
      tr.children[0].textContent = clock(f.time_s);
      tr.children[1].textContent = f.lat.toFixed(6) + ", " + f.lon.toFixed(6);
      tr.children[2].textContent = f.vehicle || "-";
      if (token) {
        ["confirm", "reject"].forEach(function (action) {
          const b = document.createElement("button");
          b.type = "button"; b.textContent = action; b.className = action;
          b.addEventListener("click", function () { send({ action: action, cell: f.cell }); });
          tr.children[3].appendChild(b);
        });
      }
      tb.appendChild(tr);
    }
    s.finds.forEach(function (f, i) {
      const row = tb.children[i];
      row.style.textDecoration = f.judged === "rejected" ? "line-through" : "";
      row.children[3].firstChild.textContent = f.judged ? f.judged + " " : "";
      row.querySelectorAll("button").forEach(function (b) {
        b.disabled = !!s.outcome || b.className + "ed" === f.judged;  // "confirm" + "ed": already said
      });
    });
    const banner = document.getElementById("banner");
    if (s.outcome) {
      banner.style.display = "block";
      banner.textContent = (s.closed ? "Mission ended: " : "Search ended, end actions under way: ") + s.outcome;
    } else if (s.paused) {
      banner.style.display = "block"; banner.textContent = "Search paused: the vehicles hold position";
    } else banner.style.display = "none";
    const off = !token || !!s.outcome;
    document.getElementById("pause").disabled = off || s.paused;
    document.getElementById("resume").disabled = off || !s.paused;
    document.getElementById("end").disabled = off;
    map.draw(scene());
    if (s.closed) polling = false;
  }

  let timer = null;
  async function poll(again) {
    try {
      const query = [];
      if (selected >= 0) query.push("vehicle=" + selected);
      if (!haveTracks) query.push("tracks=1");
      const r = await fetch("live/state" + (query.length ? "?" + query.join("&") : ""));
      if (r.ok) { show(await r.json()); haveTracks = true; }
    } catch (e) {
      if (last && last.outcome) { last.closed = true; show(last); }
      else text("message", "the controller does not answer");
    }
    if (again && polling) { clearTimeout(timer); timer = setTimeout(function () { poll(true); }, POLL_MS); }
  }

  document.getElementById("pause").addEventListener("click", function () { send({ action: "pause" }); });
  document.getElementById("resume").addEventListener("click", function () { send({ action: "resume" }); });
  document.getElementById("end").addEventListener("click", function () {
    const b = document.getElementById("end");
    if (Date.now() - armedEnd > 5000) {  // a second click within 5 s ends it: no mission ends on a slip
      armedEnd = Date.now(); b.textContent = "Click again to end"; return;
    }
    armedEnd = 0; b.textContent = "End mission"; send({ action: "end" });
  });
  ["show-tracks", "show-grid"].forEach(function (id) {
    document.getElementById(id).addEventListener("change", function () { if (map) map.draw(scene()); });
  });
  window.live = {  // for scripts and the tests: the last state, the markers drawn, a vehicle chosen, a state shown
    get state() { return last; },
    markers: function () { return map ? map.markers() : []; },
    choose: choose,
    show: show,
  };
  function start() {
    fetch("live/setup").then(function (r) {
      if (!r.ok) throw new Error("HTTP " + r.status);
      return r.json();
    }).then(function (s) { build(s); poll(true); }, function () {
      text("message", "waiting for the controller");
      setTimeout(start, 1000);
    });
  }
  start();
})();
"""


def live_js() -> str:
    return LIVE_JS.replace("__POLL_MS__", str(POLL_MS))
