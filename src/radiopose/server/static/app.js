// radiopose live dashboard: plain JavaScript, no external assets (closed networks).
// The token comes from the page address (#token=...), the form, or this browser's storage;
// every API call sends it as "Authorization: Bearer ...". Live estimates arrive as
// server-sent events read with fetch() (EventSource cannot send the header).
"use strict";

const TRAIL = 150;           // positions kept per transmitter (15 s of the demo's 100 ms packets)
const COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b"];
const state = { token: null, site: null, tracks: new Map(), health: null, moves: 0, drawn: {} };
window.radiopose = state;  // for tests and the curious (state.addEstimates, state.draw too)

function tokenFromPage() {
  const m = location.hash.match(/token=([^&]+)/);
  if (m) { sessionStorage.setItem("radiopose-token", decodeURIComponent(m[1])); history.replaceState(null, "", location.pathname); }
  return sessionStorage.getItem("radiopose-token");
}

async function api(path) {
  const r = await fetch(path, { headers: { Authorization: "Bearer " + state.token } });
  if (!r.ok) {
    let detail = r.statusText;
    try { detail = (await r.json()).detail; } catch (e) { /* keep the status text */ }
    const err = new Error(detail); err.status = r.status; throw err;
  }
  return r.json();
}

function setStatus(text, ok) {
  const el = document.getElementById("status");
  el.textContent = text; el.className = "status " + (ok ? "ok" : "bad");
}

// ---------------------------------------------------------------- drawing
function view(canvas) {
  const a = state.site.area, pad = 30;
  const w = a.x_max_m - a.x_min_m || 1, h = a.y_max_m - a.y_min_m || 1;
  const s = Math.min((canvas.width - 2 * pad) / w, (canvas.height - 2 * pad) / h);
  return { s, x: (x) => pad + (x - a.x_min_m) * s, y: (y) => canvas.height - pad - (y - a.y_min_m) * s };
}

// Device "top" (body +y) for azimuth az (anticlockwise from world +y): (-sin az, cos az).
function heading(azDeg) { const r = azDeg * Math.PI / 180; return [-Math.sin(r), Math.cos(r)]; }

function arrow(ctx, v, x, y, azDeg, len, color, width) {
  const [dx, dy] = heading(azDeg);
  const x0 = v.x(x), y0 = v.y(y), x1 = x0 + dx * len, y1 = y0 - dy * len;
  ctx.strokeStyle = color; ctx.fillStyle = color; ctx.lineWidth = width;
  ctx.beginPath(); ctx.moveTo(x0, y0); ctx.lineTo(x1, y1); ctx.stroke();
  const ang = Math.atan2(y1 - y0, x1 - x0);
  ctx.beginPath(); ctx.moveTo(x1, y1);
  ctx.lineTo(x1 - 9 * Math.cos(ang - 0.4), y1 - 9 * Math.sin(ang - 0.4));
  ctx.lineTo(x1 - 9 * Math.cos(ang + 0.4), y1 - 9 * Math.sin(ang + 0.4));
  ctx.closePath(); ctx.fill();
}

function draw() {
  const canvas = document.getElementById("floor"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (!state.site) return;
  const v = view(canvas), a = state.site.area;
  // floor area with a 1 m grid
  ctx.strokeStyle = "#eee"; ctx.lineWidth = 1;
  for (let x = Math.ceil(a.x_min_m); x <= a.x_max_m; x++) { ctx.beginPath(); ctx.moveTo(v.x(x), v.y(a.y_min_m)); ctx.lineTo(v.x(x), v.y(a.y_max_m)); ctx.stroke(); }
  for (let y = Math.ceil(a.y_min_m); y <= a.y_max_m; y++) { ctx.beginPath(); ctx.moveTo(v.x(a.x_min_m), v.y(y)); ctx.lineTo(v.x(a.x_max_m), v.y(y)); ctx.stroke(); }
  ctx.strokeStyle = "#888"; ctx.strokeRect(v.x(a.x_min_m), v.y(a.y_max_m), (a.x_max_m - a.x_min_m) * v.s, (a.y_max_m - a.y_min_m) * v.s);
  ctx.fillStyle = "#888"; ctx.font = "11px system-ui";
  ctx.fillText(`${(a.x_max_m - a.x_min_m).toFixed(1)} m × ${(a.y_max_m - a.y_min_m).toFixed(1)} m`, v.x(a.x_min_m), v.y(a.y_min_m) + 18);
  // receivers: square + facing
  for (const r of state.site.receivers) {
    arrow(ctx, v, r.x_m, r.y_m, r.azimuth_deg, 22, "#555", 1.5);
    ctx.fillStyle = "#222"; ctx.fillRect(v.x(r.x_m) - 5, v.y(r.y_m) - 5, 10, 10);
    ctx.fillText(r.receiver_id, v.x(r.x_m) + 8, v.y(r.y_m) + 14);
  }
  // transmitters: fading trail, uncertainty (when the estimate states it), position,
  // orientation arrow. state.drawn records what was drawn per transmitter (for tests).
  let k = 0;
  state.drawn = {};
  for (const [tx, t] of state.tracks) {
    const color = COLORS[k++ % COLORS.length], n = t.trail.length;
    for (let i = 1; i < n; i++) {
      ctx.globalAlpha = i / n; ctx.strokeStyle = color; ctx.lineWidth = 2;
      ctx.beginPath(); ctx.moveTo(v.x(t.trail[i - 1].x_m), v.y(t.trail[i - 1].y_m)); ctx.lineTo(v.x(t.trail[i].x_m), v.y(t.trail[i].y_m)); ctx.stroke();
    }
    ctx.globalAlpha = 1;
    const e = t.trail[n - 1], drawn = { method: e.method || null, circle_px: null, wedge_deg: null };
    uncertainty(ctx, v, e, color, drawn);
    ctx.fillStyle = color; ctx.beginPath(); ctx.arc(v.x(e.x_m), v.y(e.y_m), 5, 0, 2 * Math.PI); ctx.fill();
    arrow(ctx, v, e.x_m, e.y_m, e.azimuth_deg, 36, color, 3);
    const label = e.method ? `${tx} · ${e.method}` : tx;
    const sd = finite(e.position_std_m) ? ` ±${e.position_std_m.toFixed(2)} m` : "";
    ctx.fillStyle = color; ctx.fillText(label + sd, v.x(e.x_m) + 8, v.y(e.y_m) - 8);
    state.drawn[tx] = drawn;
  }
  document.body.dataset.uncertainty = String(Object.values(state.drawn).filter((d) => d.circle_px !== null).length);
}

function finite(x) { return typeof x === "number" && Number.isFinite(x); }

// The estimate's stated uncertainty: a circle of radius position_std_m around the
// position and a wedge of ± azimuth_std_deg around the device's top (the arrow's
// direction), each only when the estimate object carries that field.
const WEDGE_PX = 60;
function uncertainty(ctx, v, e, color, drawn) {
  const x = v.x(e.x_m), y = v.y(e.y_m);
  if (finite(e.position_std_m) && e.position_std_m >= 0) {
    const r = Math.max(e.position_std_m * v.s, 1);
    ctx.globalAlpha = 0.15; ctx.fillStyle = color;
    ctx.beginPath(); ctx.arc(x, y, r, 0, 2 * Math.PI); ctx.fill();
    ctx.globalAlpha = 0.8; ctx.strokeStyle = color; ctx.lineWidth = 1; ctx.setLineDash([4, 3]);
    ctx.beginPath(); ctx.arc(x, y, r, 0, 2 * Math.PI); ctx.stroke();
    ctx.setLineDash([]); ctx.globalAlpha = 1;
    drawn.circle_px = r;
  }
  if (finite(e.azimuth_std_deg) && e.azimuth_std_deg >= 0) {
    // canvas angles run clockwise from +x (y points down); the top points at
    // azimuth + 90° anticlockwise from world +x, i.e. -(azimuth + 90°) on the canvas
    const half = Math.min(e.azimuth_std_deg, 180) * Math.PI / 180;
    const mid = -(e.azimuth_deg + 90) * Math.PI / 180;
    ctx.globalAlpha = 0.3; ctx.fillStyle = color;
    ctx.beginPath(); ctx.moveTo(x, y);
    if (half >= Math.PI) ctx.arc(x, y, WEDGE_PX, 0, 2 * Math.PI);
    else ctx.arc(x, y, WEDGE_PX, mid - half, mid + half);
    ctx.closePath(); ctx.fill(); ctx.globalAlpha = 1;
    drawn.wedge_deg = [e.azimuth_deg - Math.min(e.azimuth_std_deg, 180), e.azimuth_deg + Math.min(e.azimuth_std_deg, 180)];
  }
}

// ---------------------------------------------------------------- tables
function fmtAge(s) { return s == null ? "never" : s < 1 ? "now" : s < 120 ? `${s.toFixed(0)} s ago` : `${(s / 60).toFixed(0)} min ago`; }

// A table row of text cells (ids are text: an id such as "a<b" is shown as is, never parsed as HTML).
function textRow(cells) {
  const tr = document.createElement("tr");
  for (const c of cells) { const td = document.createElement("td"); td.textContent = c; tr.appendChild(td); }
  return tr;
}

function renderTables() {
  const tb = document.querySelector("#tx-table tbody"); tb.replaceChildren();
  for (const [tx, t] of state.tracks) {
    const e = t.trail[t.trail.length - 1];
    // the full pose: height, pitch and roll matter at a 3-D site (docs/pose3d.md)
    tb.appendChild(textRow([tx, `${e.x_m.toFixed(2)}, ${e.y_m.toFixed(2)}, ${e.z_m.toFixed(2)}`,
      `${e.azimuth_deg.toFixed(0)}°, ${e.pitch_deg.toFixed(0)}°, ${e.roll_deg.toFixed(0)}°`, fmtAge((Date.now() - t.seen) / 1000)]));
  }
  const h = state.health; if (!h) return;
  const rb = document.querySelector("#rx-table tbody"); rb.replaceChildren();
  for (const r of h.receivers) {
    const tr = textRow([r.receiver_id, fmtAge(r.seconds_since_report), r.frames_per_s.toFixed(1),
      r.clock_offset_s == null ? "–" : (r.clock_offset_s * 1000).toFixed(2) + " ms",
      r.clock_drift_ppm == null ? "–" : r.clock_drift_ppm.toFixed(2) + " ppm"]);
    if (r.seconds_since_report == null || r.seconds_since_report > 10) tr.className = "stale";
    rb.appendChild(tr);
  }
  const lat = h.latency_s;
  document.getElementById("pipeline").textContent =
    (h.status === "ok" ? "" : `pipeline ${h.status}: ${Object.values(h.pipeline_errors || {}).map((e) => e.message).join("; ")} · `) +
    `backlog ${h.backlog_batches} batches · latency p50 ${lat.p50 == null ? "–" : (lat.p50 * 1000).toFixed(0) + " ms"}, p95 ${lat.p95 == null ? "–" : (lat.p95 * 1000).toFixed(0) + " ms"}`;
}

// ---------------------------------------------------------------- live data
function addEstimates(rows) {
  for (const e of rows) {
    let t = state.tracks.get(e.transmitter);
    if (!t) { t = { trail: [], seen: 0 }; state.tracks.set(e.transmitter, t); }
    t.trail.push(e); if (t.trail.length > TRAIL) t.trail.shift();
    t.seen = Date.now(); state.moves++;
  }
  document.body.dataset.moves = String(state.moves);
}

async function stream() {
  for (;;) {
    try {
      const r = await fetch("/api/v1/stream", { headers: { Authorization: "Bearer " + state.token } });
      if (!r.ok) throw new Error("stream: " + r.status);
      setStatus("live", true);
      const reader = r.body.getReader(), dec = new TextDecoder();
      let buf = "";
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buf += dec.decode(value, { stream: true });
        let i;
        while ((i = buf.indexOf("\n\n")) >= 0) {
          const block = buf.slice(0, i); buf = buf.slice(i + 2);
          const ev = /^event: (.*)$/m.exec(block), data = /^data: (.*)$/m.exec(block);
          if (!ev || !data) continue;
          const payload = JSON.parse(data[1]);
          if (ev[1] === "estimates") addEstimates(payload);
          else if (ev[1] === "health") state.health = payload;
        }
        draw(); renderTables();
      }
    } catch (e) { setStatus("disconnected — retrying", false); }
    await new Promise((res) => setTimeout(res, 2000));
  }
}

async function start() {
  try {
    state.site = await api("/api/v1/site");
  } catch (e) {
    document.getElementById("login").hidden = false;
    document.getElementById("login-error").textContent = state.token ? e.message : "";
    setStatus(e.status === 401 || e.status === 403 || !state.token ? "needs a viewer token" : "server unreachable", false);
    return;
  }
  document.getElementById("login").hidden = true;
  document.getElementById("site-name").textContent = `· ${state.site.name}`;
  document.body.dataset.receivers = String(state.site.receivers.length);
  draw();
  setInterval(async () => { try { state.site = await api("/api/v1/site"); draw(); } catch (e) { /* keep the last */ } }, 30000);
  stream();
}

document.getElementById("login").addEventListener("submit", (ev) => {
  ev.preventDefault();
  state.token = document.getElementById("token-input").value.trim();
  sessionStorage.setItem("radiopose-token", state.token);
  start();
});
state.addEstimates = addEstimates; state.draw = draw;
state.token = tokenFromPage();
start();
