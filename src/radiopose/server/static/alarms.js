// radiopose dashboard: the spoofing alarm panel (docs/security.md). Polls GET /api/v1/alarms
// with the page's token (window.radiopose, set by app.js) and lists the latest events;
// a transmitter whose last event is "raised" is shown in red.
"use strict";

async function pollAlarms() {
  const st = window.radiopose;
  if (!st || !st.token) return;
  try {
    const r = await fetch("/api/v1/alarms?limit=100000", { headers: { Authorization: "Bearer " + st.token } });
    if (!r.ok) return;
    const events = await r.json();
    st.alarms = events;
    const last = new Map();
    for (const e of events) last.set(e.transmitter, e);
    const tb = document.querySelector("#alarm-table tbody");
    tb.replaceChildren();
    for (const e of events.slice(-10).reverse()) {
      // text cells (app.js's textRow): a transmitter id is never parsed as HTML
      const tr = textRow([e.transmitter, e.state, `${e.timestamp_s.toFixed(2)} s`, `${e.x_m.toFixed(1)}, ${e.y_m.toFixed(1)}`]);
      if (e.state === "raised" && last.get(e.transmitter) === e) tr.className = "alarm-raised";
      tb.appendChild(tr);
    }
    const active = [...last.values()].filter((e) => e.state === "raised").length;
    document.body.dataset.alarms = String(active);
    document.getElementById("alarm-summary").textContent = active ? `${active} transmitter(s) in alarm` : "no active alarm";
  } catch (e) { /* keep the last */ }
}
setInterval(pollAlarms, 2000);
