// svss view: the page's script. It listens to /events (Server-Sent Events from the
// svss view server: "status" and "tiles") and fills the page; everything it loads comes
// from the same server (no third-party code, nothing from the internet).
"use strict";

const $ = (id) => document.getElementById(id);

function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "class") e.className = v; else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return e;
}

const num = (v, digits, unit) =>
  (typeof v === "number" && isFinite(v)) ? v.toFixed(digits) + (unit || "") : "?";

function hemi(v, pos, neg) {
  if (typeof v !== "number") return "?";
  return Math.abs(v).toFixed(6) + "°" + (v >= 0 ? pos : neg);
}

// ------------------------------------------------------------------ status

let lastStatusAt = null;

function showAlarms(s) {
  const box = $("alarms");
  box.replaceChildren();
  const alarms = (s && s.alarms) || [];
  if (!s) { box.append(el("div", {class: "none"}, "no status yet")); return; }
  if (!alarms.length) { box.append(el("div", {class: "none"}, "alarms: none")); return; }
  for (const a of alarms) {
    const sev = a.severity === "critical" ? "critical" : "warning";
    box.append(el("div", {class: "alarm " + sev, "data-alarm": a.name},
      el("span", {class: "sev"}, sev.toUpperCase()),
      el("span", {class: "name"}, a.name),
      ` since ${a.since_utc} (${num(a.age_s, 0, " s")}${a.clearing ? ", clearing" : ""}): `,
      a.message || ""));
  }
}

function row(label, value) { return el("tr", {}, el("td", {}, label), el("td", {}, value)); }

function showGlance(s) {
  const box = $("glance");
  box.replaceChildren();
  if (!s) return;
  const c = s.counters || {}, r = s.recorder || {}, pose = (s.navigation || {}).pose || {};
  const workers = s.workers || [];
  const t = el("table", {},
    row("run", `${s.run_id} — ${s.state}`),
    row("time (UTC)", s.time_utc || "?"),
    row("pings", `${num(s.ping_rate_hz, 2, "/s")} (schedule ${num(s.schedule_rate_hz, 2, "/s")}),`
      + ` last ${s.last_ping_age_s == null ? "none yet" : num(s.last_ping_age_s, 1, " s ago")};`
      + ` recorded ${c.recorded || 0}, dropped ${c.dropped || 0}`),
    row("position", pose.latitude_deg == null ? "unknown"
      : `${hemi(pose.latitude_deg, "N", "S")} ${hemi(pose.longitude_deg, "E", "W")}`
        + ` (${pose.position_source}); N ${num(pose.north_m, 1)} E ${num(pose.east_m, 1)} m`),
    row("speed", `${num(pose.speed_m_s, 2, " m/s")} (${pose.speed_source || "?"})`),
    row("heading", `${num(pose.heading_deg, 1, "°")} (${pose.heading_source || "?"})`),
    row("altitude", `${num(pose.altitude_m, 2, " m")} (${pose.altitude_source || "?"})`),
    row("disk", `${num(r.free_mib, 0, " MiB")} free`
      + (typeof r.time_left_s === "number" ? `, ${num(r.time_left_s / 60, 0, " min")} left` : "")
      + (r.stopped ? ` — STOPPED: ${r.stopped}` : "")),
    row("workers", workers.length ? workers.map((w) =>
      `${w.client}: ${w.backlog_pings == null ? "?" : w.backlog_pings} ping(s)`
      + ` (${num(w.backlog_s, 1, " s")}) behind`
      + (w.imaging_method ? `, imaging ${w.imaging_method}` : "")).join("; ") : "none heard"));
  box.append(el("h2", {}, "At a glance"), t);
}

function onStatus(m) {
  const conn = $("conn");
  document.body.classList.toggle("stale", !!m.quiet);
  if (m.quiet) {
    conn.className = "conn quiet";
    conn.textContent = m.status ? `no status from ${m.endpoint} for ${num(m.received_age_s, 0, " s")}`
      + " (run over or daemon stopped?)" : `waiting for a daemon on ${m.endpoint}`;
  } else {
    conn.className = "conn live";
    conn.textContent = `live: ${m.endpoint}`;
  }
  const s = m.status;
  $("run").textContent = s ? `run ${s.run_id} (${s.state})` : "";
  showAlarms(s);
  showGlance(s);
  $("status-text").textContent = m.text || "no status yet";
  lastStatusAt = Date.now();
}

// ------------------------------------------------------------------ tiles

let mapSrc = null;

function loadRegions() {
  fetch("/api/map").then((r) => r.json()).then((m) => {
    const svg = $("map-regions"), img = $("map");
    svg.setAttribute("viewBox", `0 0 ${img.naturalWidth} ${img.naturalHeight}`);
    svg.replaceChildren();
    for (const reg of m.regions) {
      const p = document.createElementNS("http://www.w3.org/2000/svg", "polygon");
      p.setAttribute("points", reg.points.map((xy) => xy.join(",")).join(" "));
      p.dataset.tile = reg.name;
      p.addEventListener("click", () => openTile(reg.name));
      svg.append(p);
    }
  }).catch(() => {});
}

function contactsTable(contacts) {
  if (!contacts.length) return el("div", {}, "none");
  const cols = [["#", "contact"], ["tile", "tile"], ["lat", "latitude_deg"],
    ["lon", "longitude_deg"], ["depth m", "depth_below_seabed_m"], ["excess dB", "excess_db"],
    ["N m", "north_m"], ["E m", "east_m"], ["closest pass (UTC)", "time_utc"],
    ["tail m", "tail_extent_m"], ["decay dB/m", "tail_decay_db_per_m"],
    ["\u00b1", "tail_decay_err_db_per_m"], ["late/specular dB", "late_to_specular_db"],
    ["aspect deg", "aspect_width_deg"], ["across deg", "aspect_cross_width_deg"],
    ["of a point", "aspect_point_fraction"],
    ["features", "feature_notes"], ["class", "class"],
    ["p man-made", "p_manmade"]];
  const t = el("table", {class: "list"}, el("tr", {}, ...cols.map(([h]) => el("th", {}, h))));
  for (const c of contacts) {
    t.append(el("tr", {"data-contact": c.contact}, ...cols.map(([, k]) => {
      const v = c[k];
      return el("td", {}, v == null ? "" : (typeof v === "number" && !Number.isInteger(v)
        ? v.toFixed(k.endsWith("_deg") ? 7 : 2) : v));
    })));
  }
  return t;
}

function onTiles(m) {
  $("tiles-note").textContent = m.folder ? `${m.tiles.length} in ${m.folder}` : "(no tiles yet)";
  const box = $("tiles");
  box.replaceChildren();
  for (const t of m.tiles) {
    const card = el("div", {class: "tile", "data-tile": t.name, title: "open " + t.name},
      t.quicklook ? el("img", {src: t.quicklook, alt: t.name + " quicklook"}) : "",
      el("div", {}, `${t.name}: ${t.pings} pings, ${t.detections} detection(s)`
        + (t.imaging_method ? `, ${t.imaging_method}` : "")));
    card.addEventListener("click", () => openTile(t.name));
    box.append(card);
  }
  $("contacts").replaceChildren(contactsTable(m.contacts),
    m.contacts_note ? el("div", {}, m.contacts_note) : "");
  $("map-note").textContent = m.run ? `(run ${m.run})` : "";
  showMap(m.map);
}

function showMap(src) {
  if (src === mapSrc) return;
  mapSrc = src;
  const img = $("map");
  img.onload = loadRegions;
  img.src = src;
}

function openTile(name) {
  fetch("/api/tile/" + encodeURIComponent(name)).then((r) => r.json()).then((t) => {
    $("tile-title").textContent = `${t.name} — run ${t.run_id || "?"}`;
    $("tile-meta").textContent = `${t.pings} pings; written ${t.created_utc || "?"};`
      + ` poses: ${t.poses || "?"}; sediment: ${t.sediment || "?"};`
      + ` imaging method: ${t.imaging_method || "?"};`
      + ` ${t.detections.length} detection(s) in the tile`;
    const img = $("tile-img");
    if (t.quicklook) img.src = t.quicklook; else img.removeAttribute("src");
    $("tile-contacts").replaceChildren(el("h3", {}, "Run contacts in this tile"),
      contactsTable(t.contacts));
    $("tile-view").hidden = false;
    $("tile-view").dataset.tile = t.name;
  });
}

$("tile-close").addEventListener("click", () => { $("tile-view").hidden = true; });
document.addEventListener("keydown", (e) => { if (e.key === "Escape") $("tile-view").hidden = true; });

// ------------------------------------------------------------------ the stream

const events = new EventSource("/events");
events.addEventListener("status", (e) => onStatus(JSON.parse(e.data)));
events.addEventListener("tiles", (e) => onTiles(JSON.parse(e.data)));
events.addEventListener("map", (e) => showMap(JSON.parse(e.data).map));
events.onerror = () => {
  const conn = $("conn");
  conn.className = "conn quiet";
  conn.textContent = "svss view server unreachable; retrying…";
};
// the age of the last status, between messages
setInterval(() => {
  if (lastStatusAt && Date.now() - lastStatusAt > 3000 && $("conn").classList.contains("live")) {
    $("conn").className = "conn quiet";
    document.body.classList.add("stale");
    $("conn").textContent = `no status for ${Math.round((Date.now() - lastStatusAt) / 1000)} s`;
  }
}, 1000);
