"""The map page's HTML, CSS and JavaScript (one template; swarmctl.replay.page fills in the data).

The page needs no network: the data is a JSON block in the page, the map is drawn on a canvas in Web
Mercator (the projection of web map tiles), cells are drawn as images mapped onto the grid. Only when
the page is written with a basemap tile URL does it fetch tiles from that URL.
`window.replay` gives scripts (and the browser test) the frame and the vehicle markers' positions.
The drawing itself is the live page's script (swarmctl.mission.web_page.DRAW_JS), inlined here: one
renderer for the replay and the live page.
"""

from swarmctl.mission.web_page import DRAW_JS, PAGE_HEAD

__all__ = ["DRAW_JS", "PAGE"]  # page.py fills the page in with the shared renderer

PAGE = (
    PAGE_HEAD.replace("__SIDE__", "300")
    + r"""#controls { display: flex; align-items: center; gap: 6px; margin: 8px 0; }
#slider { flex: 1; }
#frame { font-weight: bold; margin: 4px 0; }
table { border-collapse: collapse; width: 100%; font-size: 12px; }
td, th { text-align: left; padding: 2px 4px; border-bottom: 1px solid #eee; }
.sw { display: inline-block; width: 10px; height: 10px; border-radius: 5px; margin-right: 4px; }
label { display: block; margin: 3px 0; }
#attribution { position: absolute; right: 4px; bottom: 2px; font-size: 10px; color: #555;
  background: rgba(255, 255, 255, 0.7); }
</style>
</head>
<body>
<div id="app">
  <div id="map"><canvas id="canvas"></canvas><div id="attribution"></div></div>
  <div id="side">
    <h1 id="title"></h1>
    <div class="note" id="subtitle"></div>
    <div id="controls">
      <button id="play" type="button">Play</button>
      <input id="slider" type="range" min="0" value="0" step="1">
    </div>
    <div id="frame"></div>
    <label>Speed <select id="speed"><option value="2">2 frames/s</option><option value="5" selected>5 frames/s</option>
      <option value="10">10 frames/s</option><option value="25">25 frames/s</option></select></label>
    <label>Knowledge <select id="knowledge"></select></label>
    <label><input type="checkbox" id="show-tracks" checked> tracks</label>
    <label><input type="checkbox" id="show-grid" checked> grid lines</label>
    <label id="hidden-label"><input type="checkbox" id="show-hidden"> hidden targets (simulation truth)</label>
    <div id="counts" class="note"></div>
    <div id="orders" class="note"></div>
    <table id="vehicles"><thead><tr><th>vehicle</th><th>state</th><th>cell</th></tr></thead><tbody></tbody></table>
    <div class="note" id="legend">circle: vehicle now; star: target found (grey until found); diamond: hover point;
      blue cells: explored by the chosen vehicles; grey cells: blocked.</div>
  </div>
</div>
<script type="application/json" id="replay-data">__DATA__</script>
<script>
__DRAW__
</script>
<script>
"use strict";
(function () {
  const D = JSON.parse(document.getElementById("replay-data").textContent);
  const F = D.frameTimes.length, W = D.grid.w, H = D.grid.h;
  const canvas = document.getElementById("canvas");
  const mapDiv = document.getElementById("map");
  const slider = document.getElementById("slider");
  slider.max = String(F - 1);
  document.getElementById("title").textContent = D.name;
  document.getElementById("subtitle").textContent = D.subtitle;
  document.getElementById("attribution").textContent = D.basemap ? D.basemapAttribution : "";
  if (!D.hidden.length) document.getElementById("hidden-label").style.display = "none";
  const map = window.SwarmMap(canvas, mapDiv, D.grid);

  function words(b64) {
    const raw = atob(b64), out = new Uint16Array(raw.length / 2);
    for (let i = 0; i < out.length; i++) out[i] = raw.charCodeAt(2 * i) | (raw.charCodeAt(2 * i + 1) << 8);
    return out;
  }
  const first = D.knowledge ? words(D.knowledge.first) : null;
  const KV = D.knowledge ? D.knowledge.vehicles : 0;

  const knowledgeSelect = document.getElementById("knowledge");
  function option(value, text) {
    const o = document.createElement("option"); o.value = value; o.textContent = text; knowledgeSelect.appendChild(o);
  }
  if (first) {
    option("all", "all vehicles together");
    if (KV === D.vehicles.length) D.vehicles.forEach(function (v, i) { option(String(i), v.name); });
  }
  option("none", "none");
  let exploredCache = { key: null, image: null, count: 0 };
  function explored(frame) {
    const which = knowledgeSelect.value;
    if (!first || which === "none") return null;
    const key = which + ":" + frame;
    if (exploredCache.key === key) return exploredCache;
    const rows = which === "all" ? Array.from({ length: KV }, function (_, i) { return i; }) : [Number(which)];
    const mask = new Uint8Array(W * H);
    let count = 0;
    rows.forEach(function (r) {
      const base = r * W * H;
      for (let i = 0; i < W * H; i++) if (first[base + i] <= frame && !mask[i]) { mask[i] = 1; count++; }
    });
    exploredCache = {
      key: key, image: map.cellImage(function (i) { return mask[i]; }, [40, 110, 220, 110]), count: count,
    };
    return exploredCache;
  }

  let frame = 0;
  const tbody = document.querySelector("#vehicles tbody");
  D.vehicles.forEach(function (v) {
    const tr = document.createElement("tr");
    tr.innerHTML = "<td><span class='sw'></span></td><td></td><td></td>";
    tr.querySelector(".sw").style.background = v.colour;
    tr.firstChild.appendChild(document.createTextNode(v.name));
    tbody.appendChild(tr);
  });

  function draw() {
    const ex = explored(frame);
    const now = D.frameTimes[frame];
    let found = 0;
    const targets = D.targets.map(function (t) {
      const yes = t.frame <= frame; found += yes;
      return { lat: t.lat, lon: t.lon, found: yes };
    });
    const vehicles = D.vehicles.map(function (v, i) {
      const row = tbody.children[i].children;
      row[1].textContent = v.state[frame] || "";
      row[2].textContent = v.cell[frame] ? v.cell[frame].join(",") : "-";
      let n = 0;
      while (n < v.trackT.length && v.trackT[n] <= now) n++;
      return { name: v.name, colour: v.colour, lat: v.lat[frame], lon: v.lon[frame], track: v.track, done: n };
    });
    map.draw({
      area: D.area, nofly: D.nofly, buildings: D.buildings, basemap: D.basemap,
      explored: ex ? ex.image : null,
      showGrid: document.getElementById("show-grid").checked,
      showTracks: document.getElementById("show-tracks").checked,
      showHidden: document.getElementById("show-hidden").checked,
      vehicles: vehicles,
      hover: D.hover.map(function (p) {
        const v = D.vehicles[p.vehicle];
        return { lat: p.lat, lon: p.lon, colour: v ? v.colour : "#000" };
      }),
      hidden: D.hidden,
      targets: targets,
    });
    document.getElementById("frame").textContent = D.frameLabels[frame] + "  (" + D.clock[frame] + ")";
    document.getElementById("counts").textContent = found + " of " + D.targets.length + " targets found" +
      (ex ? "; " + ex.count + " cells explored" : "");
    const given = D.orders.filter(function (o) { return o.frame <= frame; });
    document.getElementById("orders").textContent = given.length ?
      "operator: " + given.map(function (o) { return o.text; }).join("; ") : "";
  }

  const trackPoints = [];
  D.vehicles.forEach(function (v) {
    const every = Math.max(1, Math.floor(v.track.length / 200));
    for (let i = 0; i < v.track.length; i += every) trackPoints.push(v.track[i]);
  });
  function resize() { map.resize(trackPoints); }
  function setFrame(f) {
    frame = Math.max(0, Math.min(F - 1, Math.round(f)));
    slider.value = String(frame);
    draw();
  }
  slider.addEventListener("input", function () { setFrame(Number(slider.value)); });
  ["knowledge", "show-tracks", "show-grid", "show-hidden"].forEach(function (id) {
    document.getElementById(id).addEventListener("change", draw);
  });
  let timer = null;
  const play = document.getElementById("play");
  function stop() { clearInterval(timer); timer = null; play.textContent = "Play"; }
  play.addEventListener("click", function () {
    if (timer) { stop(); return; }
    if (frame >= F - 1) setFrame(0);
    play.textContent = "Pause";
    timer = setInterval(function () { if (frame >= F - 1) stop(); else setFrame(frame + 1); },
                        1000 / Number(document.getElementById("speed").value));
  });
  window.addEventListener("resize", resize);
  window.replay = {
    frames: F,
    get frame() { return frame; },
    setFrame: setFrame,
    markers: function () { return map.markers(); },
  };
  draw();
  resize();
})();
</script>
</body>
</html>
"""
)
