// /operator: the safety driver's mini-display. Top-down around the car: route, stop lines,
// crosswalks, trigger volumes, the car (POSE_PREDICTED), agents with their animation,
// agents hidden by real objects (OCCLUSION) drawn hollow, the next encounter's time to
// arrival for the car and its synchronised pedestrian, localizer status, process health.
import { Bus, loadSite, loadCloud, yawOf, STATE_NAMES, POSE_STATUS, COMMAND_STATES, esc } from "./bus.js";
import { TopDown, KIND_COLOUR } from "./topdown.js";

const TOPICS = ["POSE_PREDICTED", "POSE", "AGENTS", "OCCLUSION", "STATUS", "SUPERVISOR", "LAB_EVENT", "SCENARIO_EVENT"];
const HIDDEN_BELOW = 0.5;       // visible fraction under which an agent counts as hidden by a real object
const STALE_S = 2.5;            // a STATUS heartbeat (1 Hz) older than this: the process is silent
const bus = new Bus("operator", TOPICS);
const view = new TopDown(document.getElementById("map"));
const health = new Map();       // module -> {state, last_error, rxMs}
let site = null, cloud = null;
const panel = document.getElementById("panel");

bus.on("STATUS", (m, rxMs) => health.set(m.module, { state: m.state, err: m.last_error, rxMs }));

function pose() {
  const p = bus.latest.POSE_PREDICTED || bus.latest.POSE;
  return p ? p.msg : null;
}

// Route arc length of the point nearest (x, y) (polyline, closed).
function arcOf(x, y) {
  const r = site.route;
  let best = [Infinity, 0], s = 0;
  for (let i = 0; i < r.length; i++) {
    const a = r[i], b = r[(i + 1) % r.length];
    const dx = b[0] - a[0], dy = b[1] - a[1], L = Math.hypot(dx, dy);
    const t = Math.max(0, Math.min(1, ((x - a[0]) * dx + (y - a[1]) * dy) / (L * L)));
    const d = Math.hypot(a[0] + t * dx - x, a[1] + t * dy - y);
    if (d < best[0]) best = [d, s + t * L];
    s += L;
  }
  return [best[1], s];
}

// The next stop line ahead of the car, its distance along the route, the car's and the
// synchronised pedestrian's times to arrival (pedestrian: straight line to its mark).
function nextEncounter(p, agents, scen) {
  if (!site.stop_lines.length) return null;
  const front = site.vehicle.length - site.vehicle.rear_overhang;
  const [sCar, total] = arcOf(p.position[0], p.position[1]);
  let best = null;
  for (const sl of site.stop_lines) {
    const [s] = arcOf(sl.xy[0], sl.xy[1]);
    const d = ((s - sCar - front) % total + total) % total;
    if (!best || d < best.d) best = { sl, d };
  }
  const v = Math.hypot(p.velocity[0], p.velocity[1]);
  best.car = v > 0.3 ? best.d / v : null;
  const sync = scen ? scen.sync.find((s) => s.stop_line === best.sl.id) : null;
  if (sync) {
    const a = agents.find((g) => g.id === sync.agent);
    if (a) {
      const va = Math.hypot(a.velocity[0], a.velocity[1]), da = Math.hypot(a.position[0] - sync.mark[0], a.position[1] - sync.mark[1]);
      best.ped = { id: a.id, t: da < 0.3 ? 0 : va > 0.1 ? da / va : null, d: da };
    }
  }
  return best;
}

function fmtT(t) { return t === null || t === undefined ? "—" : t > 99 ? ">99 s" : `${t.toFixed(1)} s`; }
function fmtAge(topic) { const a = bus.age(topic); return a === null ? "none" : a < 1 ? `${(a * 1000).toFixed(0)} ms` : `${a.toFixed(1)} s`; }

function draw() {
  requestAnimationFrame(draw);
  if (!site) return;
  const p = pose();
  const agentsMsg = bus.latest.AGENTS ? bus.latest.AGENTS.msg : null;
  const agents = agentsMsg ? agentsMsg.agents : [];
  const scen = agentsMsg ? site.scenario_info[agentsMsg.scenario] : null;
  if (p) { view.cx = p.position[0]; view.cy = p.position[1]; }
  view.begin();
  if (cloud) view.cloud(cloud.points);
  view.site(site);
  for (const v of scen ? scen.volumes : []) view.volume(v);
  // agents: filled = visible; hollow = hidden by a real object; faded = beyond render range
  const occ = new Map();
  if (bus.latest.OCCLUSION) for (const o of bus.latest.OCCLUSION.msg.agents) occ.set(o.agent_id, o.visible_fraction);
  const c = view.ctx;
  for (const a of agents) {
    const [u, w] = view.px(a.position[0], a.position[1]);
    const col = KIND_COLOUR[a.kind] || "#fff";
    const hidden = occ.has(a.id) && occ.get(a.id) < HIDDEN_BELOW;
    c.globalAlpha = a.in_render_range ? 1 : 0.35;
    c.beginPath(); c.arc(u, w, 0.5 * view.scale + 3, 0, 2 * Math.PI);
    c.lineWidth = 3 * devicePixelRatio;
    if (hidden) { c.setLineDash([4, 3]); c.strokeStyle = col; c.stroke(); c.setLineDash([]); }
    else { c.fillStyle = col; c.fill(); }
    c.beginPath(); c.moveTo(u, w);
    c.lineTo(u + Math.cos(a.yaw_rad) * view.scale * 1.2, w - Math.sin(a.yaw_rad) * view.scale * 1.2);
    c.strokeStyle = "#fff"; c.lineWidth = 2 * devicePixelRatio; c.stroke();
    c.globalAlpha = 1;
    view.label(a.position[0], a.position[1], `${a.id} · ${a.animation}${hidden ? " · hidden" : ""}`, col, 13);
  }
  // the car
  if (p) {
    const yaw = yawOf(p.orientation), V = site.vehicle;
    const mid = V.length / 2 - V.rear_overhang;
    const cx = p.position[0] + Math.cos(yaw) * mid, cy = p.position[1] + Math.sin(yaw) * mid;
    view.poly(view.rect(cx, cy, yaw, V.length, V.width), true, "#fff", "#e23b3b", 2);
  }
  // side panel
  const enc = p ? nextEncounter(p, agents, scen) : null;
  const speed = p ? Math.hypot(p.velocity[0], p.velocity[1]) : null;
  const loc = bus.latest.POSE ? POSE_STATUS[bus.latest.POSE.msg.status] || "?" : "no POSE";
  const lab = bus.latest.LAB_EVENT ? bus.latest.LAB_EVENT.msg.event_id : "";
  let html = `<div class="big">${speed === null ? "— m/s" : `${(speed * 3.6).toFixed(0)} km/h`}</div>`;
  html += `<div class="row"><span>localizer</span><b class="${loc === "TRACKING" ? "ok" : "bad"}">${loc}</b></div>`;
  if (enc) {
    html += `<div class="row"><span>next stop ${enc.sl.id}</span><b>${enc.d.toFixed(0)} m</b></div>`;
    html += `<div class="row"><span>car arrives</span><b>${fmtT(enc.car)}</b></div>`;
    if (enc.ped) html += `<div class="row"><span>${enc.ped.id} at mark</span><b>${enc.ped.t === 0 ? "there" : fmtT(enc.ped.t)}</b></div>`;
  }
  if (lab) html += `<div class="row"><span>lab</span><b>${lab}</b></div>`;
  html += `<div class="head">processes (STATUS)</div>`;
  const now = Date.now() + (bus.offsetMs ?? 0);
  for (const [mod, h] of [...health.entries()].sort()) {
    const age = (now - h.rxMs) / 1000;
    const st = age > STALE_S ? "SILENT" : STATE_NAMES[h.state] || "?";
    html += `<div class="row" title="${esc(h.err)}"><span>${esc(mod)}</span><b class="${st === "OK" ? "ok" : "bad"}">${st}</b></div>`;
  }
  if (!health.size) html += `<div class="row"><span>no heartbeats</span></div>`;
  // The supervisor's view (1 Hz): each command's state and restarts, so a crash loop shows
  // even while the new process's heartbeat says OK.
  const sup = bus.latest.SUPERVISOR;
  if (sup) {
    const stale = (now - sup.rxMs) / 1000 > STALE_S;
    html += `<div class="head">supervisor ${esc(sup.msg.stack)}${stale ? " (SILENT)" : ""}</div>`;
    for (const c of sup.msg.commands) {
      const st = COMMAND_STATES[c.state] || "?";
      const good = !stale && (st === "RUNNING" || st === "EXITED") && c.restarts === 0;
      html += `<div class="row" title="${esc(c.detail)}"><span>${esc(c.name)}</span><b class="${good ? "ok" : "bad"}">` +
        `${st}${c.restarts ? ` ×${c.restarts}` : ""}</b></div>`;
    }
  }
  html += `<div class="head">message age</div>`;
  for (const t of ["POSE_PREDICTED", "AGENTS", "OCCLUSION"]) html += `<div class="row"><span>${t}</span><b>${fmtAge(t)}</b></div>`;
  html += `<div class="row"><span>bridge</span><b class="${bus.connected ? "ok" : "bad"}">${bus.connected ? "connected" : "offline"}</b></div>`;
  panel.innerHTML = html;
}

window.addEventListener("resize", () => view.resize());
view.resize();
loadSite().then((s) => {
  site = s;
  if (s.route.length) { view.cx = s.route[0][0]; view.cy = s.route[0][1]; }
});
loadCloud().then((c) => { cloud = c; });
draw();
// latency probe for make bench-webui: bus-to-page time of every message, on this machine's clock
window.__lat = [];
if (location.search.includes("probe"))
  for (const t of ["POSE_PREDICTED", "AGENTS"]) bus.on(t, (m) => { if (window.__lat.length < 200000) window.__lat.push([t, Date.now() - m.utime / 1000]); });
