// The map renderer of the replay page and the live page: the area, no-fly zones and buildings, the grid
// with its blocked and explored cells, tracks, hover points, targets and vehicle markers, drawn on a
// canvas in Web Mercator (the projection of web map tiles). Pan by dragging, zoom with the wheel.
"use strict";
window.SwarmMap = function (canvas, mapDiv, grid) {
  const ctx = canvas.getContext("2d");
  const W = grid.w, H = grid.h;
  let scene = null, markers = [];

  function bits(b64, n) {
    const raw = atob(b64), out = new Uint8Array(n);
    for (let i = 0; i < n; i++) out[i] = (raw.charCodeAt(i >> 3) >> (7 - (i & 7))) & 1;
    return out;
  }
  // Web Mercator world coordinates in [0, 1]
  function world(lat, lon) {
    const s = Math.sin(lat * Math.PI / 180);
    return [(lon + 180) / 360, 0.5 - Math.log((1 + s) / (1 - s)) / (4 * Math.PI)];
  }
  const C = grid.corners.map(function (c) { return world(c[0], c[1]); }); // (0,0) (W,0) (W,H) (0,H)
  const view = { x: 0.5, y: 0.5, scale: 1, fitted: false };
  function screen(p) {
    return [(p[0] - view.x) * view.scale + canvas.width / 2, (p[1] - view.y) * view.scale + canvas.height / 2];
  }
  function project(lat, lon) { return screen(world(lat, lon)); }

  // the view that shows the grid and the given [lon, lat] points
  function fit(points) {
    const xs = C.map(function (c) { return c[0]; }), ys = C.map(function (c) { return c[1]; });
    (points || []).forEach(function (q) { const p = world(q[1], q[0]); xs.push(p[0]); ys.push(p[1]); });
    const x0 = Math.min.apply(null, xs), x1 = Math.max.apply(null, xs);
    const y0 = Math.min.apply(null, ys), y1 = Math.max.apply(null, ys);
    view.x = (x0 + x1) / 2; view.y = (y0 + y1) / 2;
    view.scale = 0.9 * Math.min(canvas.width / Math.max(x1 - x0, 1e-9), canvas.height / Math.max(y1 - y0, 1e-9));
  }

  // a W x H image of the cells where test(x * H + y) holds, in one colour
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
  const blocked = bits(grid.blocked, W * H);
  const blockedImage = cellImage(function (i) { return blocked[i]; }, [90, 90, 90, 200]);
  function gridTransform() {
    const s00 = screen(C[0]), s10 = screen(C[1]), s01 = screen(C[3]);
    ctx.setTransform((s10[0] - s00[0]) / W, (s10[1] - s00[1]) / W, -(s01[0] - s00[0]) / H, -(s01[1] - s00[1]) / H,
                     s01[0], s01[1]);
    ctx.imageSmoothingEnabled = false;
  }

  const tiles = {};
  function drawTiles(basemap) {
    if (!basemap) return;
    const z = Math.max(0, Math.min(19, Math.round(Math.log2(view.scale / 256))));
    const n = Math.pow(2, z), size = view.scale / n;
    const tl = [view.x - canvas.width / 2 / view.scale, view.y - canvas.height / 2 / view.scale];
    const br = [view.x + canvas.width / 2 / view.scale, view.y + canvas.height / 2 / view.scale];
    for (let tx = Math.floor(tl[0] * n); tx <= Math.floor(br[0] * n); tx++) {
      for (let ty = Math.max(0, Math.floor(tl[1] * n)); ty <= Math.min(n - 1, Math.floor(br[1] * n)); ty++) {
        const url = basemap.replace("{z}", z).replace("{x}", ((tx % n) + n) % n).replace("{y}", ty);
        let img = tiles[url];
        if (!img) { img = tiles[url] = new Image(); img.onload = redraw; img.src = url; }
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

  // scene: area, nofly, buildings ([lon, lat] rings), basemap (a tile URL or null), explored (a cellImage
  // or null), showGrid, showTracks, vehicles ({name, colour, lat, lon, track, done: the track points
  // flown so far, selected}), hover ({lat, lon, colour}), hidden ({lat, lon}), targets ({lat, lon, found})
  function draw(s) {
    scene = s;
    const dpr = window.devicePixelRatio || 1;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    drawTiles(s.basemap);
    ctx.lineWidth = 2; ctx.strokeStyle = "#2b5d2b"; ctx.fillStyle = "rgba(120, 170, 120, 0.12)";
    (s.area || []).forEach(function (r) { ring(r, true); ctx.fill(); ctx.stroke(); });
    ctx.strokeStyle = "#b00"; ctx.fillStyle = "rgba(200, 0, 0, 0.12)";
    (s.nofly || []).forEach(function (r) { ring(r, true); ctx.fill(); ctx.stroke(); });
    ctx.save(); gridTransform(); ctx.drawImage(blockedImage, 0, 0);
    if (s.explored) ctx.drawImage(s.explored, 0, 0);
    ctx.restore();
    const s00 = screen(C[0]), s10 = screen(C[1]);
    const cellPx = Math.hypot(s10[0] - s00[0], s10[1] - s00[1]) / W;
    if (s.showGrid && cellPx >= 6) {
      ctx.save(); gridTransform(); ctx.beginPath();
      for (let x = 0; x <= W; x++) { ctx.moveTo(x, 0); ctx.lineTo(x, H); }
      for (let y = 0; y <= H; y++) { ctx.moveTo(0, y); ctx.lineTo(W, y); }
      ctx.restore(); ctx.strokeStyle = "rgba(0, 0, 0, 0.15)"; ctx.lineWidth = 1; ctx.stroke();
    }
    ctx.strokeStyle = "#8b4513"; ctx.lineWidth = 1; ctx.fillStyle = "rgba(139, 69, 19, 0.15)";
    (s.buildings || []).forEach(function (r) { ring(r, true); ctx.fill(); ctx.stroke(); });
    if (s.showTracks) {
      s.vehicles.forEach(function (v) {
        if (v.track.length < 2) return;
        const n = v.done === undefined ? v.track.length : v.done;
        if (n < v.track.length) {
          ctx.strokeStyle = v.colour; ctx.globalAlpha = 0.25; ctx.lineWidth = 1.5;
          ring(v.track, false); ctx.stroke();
        }
        ctx.strokeStyle = v.colour; ctx.globalAlpha = 0.95; ctx.lineWidth = 2;
        if (n > 1) { ring(v.track.slice(0, n), false); ctx.stroke(); }
        ctx.globalAlpha = 1;
      });
    }
    (s.hover || []).forEach(function (p) {
      const q = project(p.lat, p.lon);
      ctx.beginPath(); ctx.moveTo(q[0], q[1] - 7); ctx.lineTo(q[0] + 7, q[1]); ctx.lineTo(q[0], q[1] + 7);
      ctx.lineTo(q[0] - 7, q[1]); ctx.closePath();
      ctx.strokeStyle = p.colour || "#000"; ctx.lineWidth = 2; ctx.stroke();
    });
    if (s.showHidden) {
      (s.hidden || []).forEach(function (p) {
        const q = project(p.lat, p.lon);
        ctx.strokeStyle = "#d00"; ctx.lineWidth = 3; ctx.beginPath();
        ctx.moveTo(q[0] - 6, q[1] - 6); ctx.lineTo(q[0] + 6, q[1] + 6);
        ctx.moveTo(q[0] + 6, q[1] - 6); ctx.lineTo(q[0] - 6, q[1] + 6);
        ctx.stroke();
      });
    }
    (s.targets || []).forEach(function (t) {
      star(project(t.lat, t.lon), 10, t.found ? "gold" : "rgba(160, 160, 160, 0.6)");
    });
    markers = [];
    s.vehicles.forEach(function (v) {
      if (v.lat === null || v.lon === null || v.lat === undefined) { markers.push(null); return; }
      const q = project(v.lat, v.lon);
      ctx.beginPath(); ctx.arc(q[0], q[1], v.selected ? 9 : 7, 0, 2 * Math.PI); ctx.fillStyle = v.colour; ctx.fill();
      ctx.strokeStyle = "#000"; ctx.lineWidth = v.selected ? 3 : 1.5; ctx.stroke();
      ctx.fillStyle = "#000"; ctx.font = "11px system-ui, sans-serif"; ctx.fillText(v.name, q[0] + 9, q[1] - 8);
      markers.push({ name: v.name, x: q[0] / dpr, y: q[1] / dpr });
    });
  }
  function redraw() { if (scene) draw(scene); }

  // the vehicle marker at a point of the page (CSS pixels in the map), or -1
  function markerAt(x, y) {
    let best = -1, bestD = 14;
    markers.forEach(function (m, i) {
      if (!m) return;
      const d = Math.hypot(m.x - x, m.y - y);
      if (d < bestD) { best = i; bestD = d; }
    });
    return best;
  }

  function resize(points) {
    const dpr = window.devicePixelRatio || 1, r = mapDiv.getBoundingClientRect();
    const old = [canvas.width, canvas.height];
    canvas.width = Math.max(1, Math.round(r.width * dpr)); canvas.height = Math.max(1, Math.round(r.height * dpr));
    canvas.style.width = r.width + "px"; canvas.style.height = r.height + "px";
    if (!view.fitted) { fit(points); view.fitted = true; } else { view.scale *= canvas.width / Math.max(old[0], 1); }
    redraw();
  }
  let drag = null, moved = false;
  mapDiv.addEventListener("mousedown", function (e) {
    drag = [e.clientX, e.clientY]; moved = false; mapDiv.style.cursor = "grabbing";
  });
  window.addEventListener("mouseup", function () { drag = null; mapDiv.style.cursor = "grab"; });
  window.addEventListener("mousemove", function (e) {
    if (!drag) return;
    const dpr = window.devicePixelRatio || 1;
    if (Math.abs(e.clientX - drag[0]) + Math.abs(e.clientY - drag[1]) > 0) moved = true;
    view.x -= (e.clientX - drag[0]) * dpr / view.scale; view.y -= (e.clientY - drag[1]) * dpr / view.scale;
    drag = [e.clientX, e.clientY]; redraw();
  });
  mapDiv.addEventListener("wheel", function (e) {
    e.preventDefault();
    const dpr = window.devicePixelRatio || 1, r = mapDiv.getBoundingClientRect();
    const mx = (e.clientX - r.left) * dpr - canvas.width / 2, my = (e.clientY - r.top) * dpr - canvas.height / 2;
    const before = [view.x + mx / view.scale, view.y + my / view.scale];
    view.scale *= Math.exp(-e.deltaY * 0.0015);
    view.x = before[0] - mx / view.scale; view.y = before[1] - my / view.scale;
    redraw();
  }, { passive: false });

  return {
    draw: draw,
    redraw: redraw,
    resize: resize,
    cellImage: cellImage,
    bits: bits,
    markerAt: markerAt,
    dragged: function () { return moved; },
    markers: function () { return markers.slice(); },
  };
};
