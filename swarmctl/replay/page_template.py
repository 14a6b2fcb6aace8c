"""The map page's HTML, CSS and JavaScript (one template; swarmctl.replay.page fills in the data).

The page needs no network: the data is a JSON block in the page, the map is drawn on a canvas in Web
Mercator (the projection of web map tiles), cells are drawn as images mapped onto the grid. Only when
the page is written with a basemap tile URL does it fetch tiles from that URL.
`window.replay` gives scripts (and the browser test) the frame and the vehicle markers' positions.
"""

PAGE = r"""<!DOCTYPE html>
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
#side { width: 300px; overflow-y: auto; border-left: 1px solid #ccc; padding: 10px; box-sizing: border-box; }
#side h1 { font-size: 15px; margin: 0 0 4px; }
.note { color: #666; font-size: 11px; margin: 2px 0 8px; }
#controls { display: flex; align-items: center; gap: 6px; margin: 8px 0; }
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
    <table id="vehicles"><thead><tr><th>vehicle</th><th>state</th><th>cell</th></tr></thead><tbody></tbody></table>
    <div class="note" id="legend">circle: vehicle now; star: target found (grey until found); diamond: hover point;
      blue cells: explored by the chosen vehicles; grey cells: blocked.</div>
  </div>
</div>
<script type="application/json" id="replay-data">__DATA__</script>
<script>
"use strict";
(function () {
  const D = JSON.parse(document.getElementById("replay-data").textContent);
  const F = D.frameTimes.length, W = D.grid.w, H = D.grid.h;
  const canvas = document.getElementById("canvas"), ctx = canvas.getContext("2d");
  const mapDiv = document.getElementById("map");
  const slider = document.getElementById("slider");
  slider.max = String(F - 1);
  document.getElementById("title").textContent = D.name;
  document.getElementById("subtitle").textContent = D.subtitle;
  document.getElementById("attribution").textContent = D.basemap ? D.basemapAttribution : "";
  if (!D.hidden.length) document.getElementById("hidden-label").style.display = "none";

  function bits(b64, n) {
    const raw = atob(b64), out = new Uint8Array(n);
    for (let i = 0; i < n; i++) out[i] = (raw.charCodeAt(i >> 3) >> (7 - (i & 7))) & 1;
    return out;
  }
  function words(b64) {
    const raw = atob(b64), out = new Uint16Array(raw.length / 2);
    for (let i = 0; i < out.length; i++) out[i] = raw.charCodeAt(2 * i) | (raw.charCodeAt(2 * i + 1) << 8);
    return out;
  }
  const blocked = bits(D.grid.blocked, W * H);
  const first = D.knowledge ? words(D.knowledge.first) : null;
  const KV = D.knowledge ? D.knowledge.vehicles : 0;

  // Web Mercator world coordinates in [0, 1]
  function world(lat, lon) {
    const s = Math.sin(lat * Math.PI / 180);
    return [(lon + 180) / 360, 0.5 - Math.log((1 + s) / (1 - s)) / (4 * Math.PI)];
  }
  const C = D.grid.corners.map(function (c) { return world(c[0], c[1]); }); // (0,0) (W,0) (W,H) (0,H)
  const view = { x: 0.5, y: 0.5, scale: 1 };
  function screen(p) {
    return [(p[0] - view.x) * view.scale + canvas.width / 2, (p[1] - view.y) * view.scale + canvas.height / 2];
  }
  function project(lat, lon) { return screen(world(lat, lon)); }

  function fit() {
    let xs = C.map(function (c) { return c[0]; }), ys = C.map(function (c) { return c[1]; });
    D.vehicles.forEach(function (v) {
      for (let i = 0; i < v.track.length; i += Math.max(1, Math.floor(v.track.length / 200))) {
        const p = world(v.track[i][1], v.track[i][0]); xs.push(p[0]); ys.push(p[1]);
      }
    });
    const x0 = Math.min.apply(null, xs), x1 = Math.max.apply(null, xs);
    const y0 = Math.min.apply(null, ys), y1 = Math.max.apply(null, ys);
    view.x = (x0 + x1) / 2; view.y = (y0 + y1) / 2;
    view.scale = 0.9 * Math.min(canvas.width / Math.max(x1 - x0, 1e-9), canvas.height / Math.max(y1 - y0, 1e-9));
  }

  function cellImage(test, rgba) {
    const img = document.createElement("canvas");
    img.width = W; img.height = H;
    const c = img.getContext("2d"), data = c.createImageData(W, H);
    for (let x = 0; x < W; x++) for (let y = 0; y < H; y++) {
      if (!test(x * H + y)) continue;
      const k = 4 * ((H - 1 - y) * W + x);
      data.data[k] = rgba[0]; data.data[k + 1] = rgba[1]; data.data[k + 2] = rgba[2]; data.data[k + 3] = rgba[3];
    }
    c.putImageData(data, 0, 0);
    return img;
  }
  const blockedImage = cellImage(function (i) { return blocked[i]; }, [90, 90, 90, 200]);
  function gridTransform() {
    const s00 = screen(C[0]), s10 = screen(C[1]), s01 = screen(C[3]);
    ctx.setTransform((s10[0] - s00[0]) / W, (s10[1] - s00[1]) / W, -(s01[0] - s00[0]) / H, -(s01[1] - s00[1]) / H,
                     s01[0], s01[1]);
    ctx.imageSmoothingEnabled = false;
  }

  const tiles = {};
  function drawTiles() {
    if (!D.basemap) return;
    const z = Math.max(0, Math.min(19, Math.round(Math.log2(view.scale / 256))));
    const n = Math.pow(2, z), size = view.scale / n;
    const tl = [view.x - canvas.width / 2 / view.scale, view.y - canvas.height / 2 / view.scale];
    const br = [view.x + canvas.width / 2 / view.scale, view.y + canvas.height / 2 / view.scale];
    for (let tx = Math.floor(tl[0] * n); tx <= Math.floor(br[0] * n); tx++) {
      for (let ty = Math.max(0, Math.floor(tl[1] * n)); ty <= Math.min(n - 1, Math.floor(br[1] * n)); ty++) {
        const url = D.basemap.replace("{z}", z).replace("{x}", ((tx % n) + n) % n).replace("{y}", ty);
        let img = tiles[url];
        if (!img) { img = tiles[url] = new Image(); img.onload = draw; img.src = url; }
        if (img.complete && img.naturalWidth) {
          const p = screen([tx / n, ty / n]);
          ctx.drawImage(img, p[0], p[1], size + 0.5, size + 0.5);
        }
      }
    }
  }

  function ring(points, close) {
    ctx.beginPath();
    points.forEach(function (p, i) {
      const s = project(p[1], p[0]);
      if (i) ctx.lineTo(s[0], s[1]); else ctx.moveTo(s[0], s[1]);
    });
    if (close) ctx.closePath();
  }
  function star(s, r, fill) {
    ctx.beginPath();
    for (let i = 0; i < 10; i++) {
      const a = Math.PI / 2 + i * Math.PI / 5, rr = i % 2 ? r * 0.45 : r;
      ctx.lineTo(s[0] + rr * Math.cos(a), s[1] - rr * Math.sin(a));
    }
    ctx.closePath(); ctx.fillStyle = fill; ctx.fill(); ctx.strokeStyle = "#000"; ctx.lineWidth = 1; ctx.stroke();
  }

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
    exploredCache = { key: key, image: cellImage(function (i) { return mask[i]; }, [40, 110, 220, 110]), count: count };
    return exploredCache;
  }

  let frame = 0, markers = [];
  const tbody = document.querySelector("#vehicles tbody");
  D.vehicles.forEach(function (v) {
    const tr = document.createElement("tr");
    tr.innerHTML = "<td><span class='sw'></span></td><td></td><td></td>";
    tr.querySelector(".sw").style.background = v.colour;
    tr.firstChild.appendChild(document.createTextNode(v.name));
    tbody.appendChild(tr);
  });

  function draw() {
    const dpr = window.devicePixelRatio || 1;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    drawTiles();
    ctx.lineWidth = 2; ctx.strokeStyle = "#2b5d2b"; ctx.fillStyle = "rgba(120, 170, 120, 0.12)";
    D.area.forEach(function (r) { ring(r, true); ctx.fill(); ctx.stroke(); });
    ctx.strokeStyle = "#b00"; ctx.fillStyle = "rgba(200, 0, 0, 0.12)";
    D.nofly.forEach(function (r) { ring(r, true); ctx.fill(); ctx.stroke(); });
    ctx.save(); gridTransform(); ctx.drawImage(blockedImage, 0, 0);
    const ex = explored(frame);
    if (ex) ctx.drawImage(ex.image, 0, 0);
    ctx.restore();
    const s00 = screen(C[0]), s10 = screen(C[1]);
    const cellPx = Math.hypot(s10[0] - s00[0], s10[1] - s00[1]) / W;
    if (document.getElementById("show-grid").checked && cellPx >= 6) {
      ctx.save(); gridTransform(); ctx.beginPath();
      for (let x = 0; x <= W; x++) { ctx.moveTo(x, 0); ctx.lineTo(x, H); }
      for (let y = 0; y <= H; y++) { ctx.moveTo(0, y); ctx.lineTo(W, y); }
      ctx.restore(); ctx.strokeStyle = "rgba(0, 0, 0, 0.15)"; ctx.lineWidth = 1; ctx.stroke();
    }
    ctx.strokeStyle = "#8b4513"; ctx.lineWidth = 1; ctx.fillStyle = "rgba(139, 69, 19, 0.15)";
    D.buildings.forEach(function (r) { ring(r, true); ctx.fill(); ctx.stroke(); });
    const now = D.frameTimes[frame];
    if (document.getElementById("show-tracks").checked) {
      D.vehicles.forEach(function (v) {
        if (v.track.length < 2) return;
        ctx.strokeStyle = v.colour; ctx.globalAlpha = 0.25; ctx.lineWidth = 1.5;
        ring(v.track, false); ctx.stroke();
        let n = 0;
        while (n < v.trackT.length && v.trackT[n] <= now) n++;
        ctx.globalAlpha = 0.95; ctx.lineWidth = 2;
        if (n > 1) { ring(v.track.slice(0, n), false); ctx.stroke(); }
        ctx.globalAlpha = 1;
      });
    }
    D.hover.forEach(function (p) {
      const s = project(p.lat, p.lon), v = D.vehicles[p.vehicle];
      ctx.beginPath(); ctx.moveTo(s[0], s[1] - 7); ctx.lineTo(s[0] + 7, s[1]); ctx.lineTo(s[0], s[1] + 7);
      ctx.lineTo(s[0] - 7, s[1]); ctx.closePath();
      ctx.strokeStyle = v ? v.colour : "#000"; ctx.lineWidth = 2; ctx.stroke();
    });
    if (document.getElementById("show-hidden").checked) {
      D.hidden.forEach(function (p) {
        const s = project(p.lat, p.lon);
        ctx.strokeStyle = "#d00"; ctx.lineWidth = 3; ctx.beginPath();
        ctx.moveTo(s[0] - 6, s[1] - 6); ctx.lineTo(s[0] + 6, s[1] + 6);
        ctx.moveTo(s[0] + 6, s[1] - 6); ctx.lineTo(s[0] - 6, s[1] + 6);
        ctx.stroke();
      });
    }
    let found = 0;
    D.targets.forEach(function (t) {
      const yes = t.frame <= frame; found += yes;
      star(project(t.lat, t.lon), 10, yes ? "gold" : "rgba(160, 160, 160, 0.6)");
    });
    markers = [];
    D.vehicles.forEach(function (v, i) {
      const lat = v.lat[frame], lon = v.lon[frame];
      const row = tbody.children[i].children;
      row[1].textContent = v.state[frame] || "";
      row[2].textContent = v.cell[frame] ? v.cell[frame].join(",") : "-";
      if (lat === null || lon === null) { markers.push(null); return; }
      const s = project(lat, lon);
      ctx.beginPath(); ctx.arc(s[0], s[1], 7, 0, 2 * Math.PI); ctx.fillStyle = v.colour; ctx.fill();
      ctx.strokeStyle = "#000"; ctx.lineWidth = 1.5; ctx.stroke();
      ctx.fillStyle = "#000"; ctx.font = "11px system-ui, sans-serif"; ctx.fillText(v.name, s[0] + 9, s[1] - 8);
      markers.push({ name: v.name, x: s[0] / dpr, y: s[1] / dpr });
    });
    document.getElementById("frame").textContent = D.frameLabels[frame] + "  (" + D.clock[frame] + ")";
    document.getElementById("counts").textContent = found + " of " + D.targets.length + " targets found" +
      (ex ? "; " + ex.count + " cells explored" : "");
  }

  function resize() {
    const dpr = window.devicePixelRatio || 1, r = mapDiv.getBoundingClientRect();
    const old = [canvas.width, canvas.height];
    canvas.width = Math.max(1, Math.round(r.width * dpr)); canvas.height = Math.max(1, Math.round(r.height * dpr));
    canvas.style.width = r.width + "px"; canvas.style.height = r.height + "px";
    if (!view.fitted) { fit(); view.fitted = true; } else { view.scale *= canvas.width / Math.max(old[0], 1); }
    draw();
  }
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
  let drag = null;
  mapDiv.addEventListener("mousedown", function (e) {
    drag = [e.clientX, e.clientY]; mapDiv.style.cursor = "grabbing";
  });
  window.addEventListener("mouseup", function () { drag = null; mapDiv.style.cursor = "grab"; });
  window.addEventListener("mousemove", function (e) {
    if (!drag) return;
    const dpr = window.devicePixelRatio || 1;
    view.x -= (e.clientX - drag[0]) * dpr / view.scale; view.y -= (e.clientY - drag[1]) * dpr / view.scale;
    drag = [e.clientX, e.clientY]; draw();
  });
  mapDiv.addEventListener("wheel", function (e) {
    e.preventDefault();
    const dpr = window.devicePixelRatio || 1, r = mapDiv.getBoundingClientRect();
    const mx = (e.clientX - r.left) * dpr - canvas.width / 2, my = (e.clientY - r.top) * dpr - canvas.height / 2;
    const before = [view.x + mx / view.scale, view.y + my / view.scale];
    view.scale *= Math.exp(-e.deltaY * 0.0015);
    view.x = before[0] - mx / view.scale; view.y = before[1] - my / view.scale;
    draw();
  }, { passive: false });
  window.addEventListener("resize", resize);
  window.replay = {
    frames: F,
    get frame() { return frame; },
    setFrame: setFrame,
    markers: function () { return markers.slice(); },
  };
  resize();
})();
</script>
</body>
</html>
"""
