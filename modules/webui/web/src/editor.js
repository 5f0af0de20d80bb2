// /editor: the staging editor. The site's point cloud in 3-D and top-down; agents, path
// waypoints, volume centres and prism corners are dragged in the top-down view and snap
// to the ground; every edit is checked by the bridge with scenario-check itself (messages
// name the element); Save writes SITE/scenarios/NAME.yaml through the bridge, which
// refuses files with errors and paths outside that folder; Preview runs the scenario
// against the lab twin and plays it on a time slider.
import * as THREE from "three";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
import { Bus, loadSite, loadCloud } from "./bus.js";
import { makeRenderer, cloudPoints, siteObjects, agentFigure, carBox, lights } from "./scene.js";

const PICK_PX = 14;          // a handle within this many pixels of the pointer is grabbed
const CHECK_DEBOUNCE_MS = 250;
const $ = (id) => document.getElementById(id);
const bus = new Bus("editor", []);
let site = null, cloud = { points: new Float32Array(0), ground: () => 0 };
let name = null, model = null, issues = [], selected = null, preview = null;
const r3 = makeRenderer($("v3d")), rTop = makeRenderer($("vtop"));
const scene = new THREE.Scene();
lights(scene);
const cam3 = new THREE.PerspectiveCamera(50, 1, 0.5, 3000);
cam3.up.set(0, 0, 1);
const orbit = new OrbitControls(cam3, $("v3d"));
const camTop = new THREE.OrthographicCamera(-1, 1, 1, -1, 1, 2000);
const top = { cx: 0, cy: 0, mpp: 0.15 };   // metres per CSS pixel
const staging = new THREE.Group();
const previewGroup = new THREE.Group();
scene.add(staging, previewGroup);

// ---------------------------------------------------------------- model <-> handles
const r2 = (v) => Math.round(v * 100) / 100;
function handles() {
  const h = [];
  if (!model) return h;
  for (const a of model.agents || []) h.push({ key: `agent:${a.id}`, el: `agent ${a.id}`, xy: a.start, set: (x, y) => { a.start = [x, y]; }, kind: a.kind, yaw: a.yaw_deg || 0 });
  for (const b of model.behaviours || []) (b.path || []).forEach((w, k) =>
    h.push({ key: `wp:${b.id}:${k}`, el: `behaviour ${b.id}`, xy: w.to, set: (x, y) => { w.to = [x, y]; }, wp: true }));
  for (const v of model.volumes || []) {
    if (v.type === "prism") v.points.forEach((p, k) => h.push({ key: `vol:${v.id}:${k}`, el: `volume ${v.id}`, xy: p, set: (x, y) => { v.points[k] = [x, y]; }, vol: true }));
    else h.push({ key: `vol:${v.id}`, el: `volume ${v.id}`, xy: v.center, set: (x, y) => { v.center = [x, y]; }, vol: true });
  }
  return h;
}

function badElements() { return new Set(issues.filter((i) => i.severity === "error").map((i) => i.element)); }

function rebuild() {
  redraw();
  staging.clear();
  if (!model) return;
  const bad = badElements(), g = cloud.ground;
  const mark = (el, base) => bad.has(el) ? 0xff3030 : selected === el ? 0xffffff : base;
  for (const v of model.volumes || []) {
    const el = `volume ${v.id}`, col = mark(el, 0x4fa3ff);
    let shape, z0 = 0, hgt = 3;
    if (v.type === "box") {
      const [l, w, hh] = v.size; hgt = hh; z0 = v.z0 || 0;
      shape = new THREE.Shape([[-l / 2, -w / 2], [l / 2, -w / 2], [l / 2, w / 2], [-l / 2, w / 2]].map(([a, b]) => new THREE.Vector2(a, b)));
    } else if (v.type === "cylinder") {
      shape = new THREE.Shape(); shape.absarc(0, 0, v.radius, 0, 2 * Math.PI); hgt = v.height ?? 3; z0 = v.z0 || 0;
    } else {
      shape = new THREE.Shape(v.points.map(([a, b]) => new THREE.Vector2(a, b))); z0 = (v.z || [0, 3])[0]; hgt = (v.z || [0, 3])[1] - z0;
    }
    const geo = new THREE.ExtrudeGeometry(shape, { depth: hgt, bevelEnabled: false });
    const m = new THREE.Mesh(geo, new THREE.MeshBasicMaterial({ color: col, transparent: true, opacity: 0.22, depthWrite: false }));
    const edges = new THREE.LineSegments(new THREE.EdgesGeometry(geo), new THREE.LineBasicMaterial({ color: col }));
    const grp = new THREE.Group(); grp.add(m, edges);
    if (v.type !== "prism") { grp.position.set(v.center[0], v.center[1], g(v.center[0], v.center[1]) + z0); grp.rotation.z = (v.yaw_deg || 0) * Math.PI / 180; }
    else grp.position.z = z0;
    staging.add(grp);
  }
  for (const b of model.behaviours || []) {
    const agent = (model.agents || []).find((a) => a.id === b.agent);
    const pts = (agent ? [agent.start] : []).concat((b.path || []).map((w) => w.to)).map(([x, y]) => new THREE.Vector3(x, y, g(x, y) + 0.1));
    staging.add(new THREE.Line(new THREE.BufferGeometry().setFromPoints(pts), new THREE.LineBasicMaterial({ color: mark(`behaviour ${b.id}`, 0x7ee787) })));
  }
  for (const h of handles()) {
    let obj;
    if (h.kind) {
      obj = agentFigure(h.kind);
      const disc = new THREE.Mesh(new THREE.CircleGeometry(0.7, 20), new THREE.MeshBasicMaterial({ color: mark(h.el, 0xffb020), transparent: true, opacity: 0.6 }));
      disc.position.z = 0.03;
      obj.add(disc);
      obj.rotation.z = h.yaw * Math.PI / 180;
      const c = mark(h.el, null);
      if (c !== null) obj.userData.material.color.setHex(c);
    } else {
      obj = new THREE.Mesh(new THREE.SphereGeometry(h.wp ? 0.35 : 0.45, 12, 8), new THREE.MeshBasicMaterial({ color: mark(h.el, h.wp ? 0x7ee787 : 0x4fa3ff) }));
    }
    obj.position.set(h.xy[0], h.xy[1], g(h.xy[0], h.xy[1]) + (h.kind ? 0 : 0.2));   // snapped to the ground
    staging.add(obj);
  }
}

// ---------------------------------------------------------------- top-down view geometry
function topSize() { const c = $("vtop"); return [c.clientWidth, c.clientHeight]; }
function topToMap(px, py) { const [w, h] = topSize(); return [top.cx + (px - w / 2) * top.mpp, top.cy - (py - h / 2) * top.mpp]; }
function mapToTop(x, y) { const [w, h] = topSize(); return [w / 2 + (x - top.cx) / top.mpp, h / 2 - (y - top.cy) / top.mpp]; }
function placeTop() {
  const [w, h] = topSize();
  camTop.left = -w / 2 * top.mpp; camTop.right = w / 2 * top.mpp; camTop.top = h / 2 * top.mpp; camTop.bottom = -h / 2 * top.mpp;
  camTop.position.set(top.cx, top.cy, 1000); camTop.up.set(0, 1, 0); camTop.lookAt(top.cx, top.cy, 0);
  camTop.updateProjectionMatrix();
}

let drag = null;
$("vtop").addEventListener("pointerdown", (ev) => {
  const [mx, my] = topToMap(ev.offsetX, ev.offsetY);
  let best = null;
  for (const h of handles()) {
    const d = Math.hypot(h.xy[0] - mx, h.xy[1] - my) / top.mpp;
    if (d < PICK_PX && (!best || d < best.d)) best = { h, d };
  }
  $("vtop").setPointerCapture(ev.pointerId);
  if (best) { drag = { h: best.h, moved: false }; select(best.h.el); }
  else drag = { pan: [ev.offsetX, ev.offsetY, top.cx, top.cy] };
});
$("vtop").addEventListener("pointermove", (ev) => {
  if (!drag) return;
  if (drag.pan) {
    const [x0, y0, cx, cy] = drag.pan;
    top.cx = cx - (ev.offsetX - x0) * top.mpp; top.cy = cy + (ev.offsetY - y0) * top.mpp;
    redraw();
    return;
  }
  const [mx, my] = topToMap(ev.offsetX, ev.offsetY);
  drag.h.set(r2(mx), r2(my));
  drag.moved = true;
  rebuild();
});
$("vtop").addEventListener("pointerup", () => { if (drag && drag.moved) changed(); drag = null; });
$("vtop").addEventListener("wheel", (ev) => {
  ev.preventDefault();
  const [mx, my] = topToMap(ev.offsetX, ev.offsetY);
  top.mpp *= Math.exp(ev.deltaY * 0.001);
  top.mpp = Math.min(2, Math.max(0.02, top.mpp));
  const [nx, ny] = topToMap(ev.offsetX, ev.offsetY);
  top.cx += mx - nx; top.cy += my - ny;
  redraw();
}, { passive: false });

// ---------------------------------------------------------------- checking, saving
let checkTimer = null, checkSeq = 0;
function changed() {
  rebuild(); list();
  clearTimeout(checkTimer);
  checkTimer = setTimeout(check, CHECK_DEBOUNCE_MS);
}
async function check() {
  const seq = ++checkSeq;
  $("checkstate").textContent = "checking…";
  try {
    const r = await bus.call("scenario.check", { name, model });
    if (seq !== checkSeq) return;
    issues = r.issues;
    $("checkstate").textContent = r.ok ? "scenario-check: ok" : "scenario-check: errors";
    $("checkstate").className = r.ok ? "ok" : "bad";
  } catch (e) {
    issues = [{ severity: "error", element: "", line: 0, message: e.message }];
    $("checkstate").textContent = "check failed"; $("checkstate").className = "bad";
  }
  showIssues(); rebuild(); list();
}
function showIssues() {
  $("issues").innerHTML = issues.map((i) =>
    `<div class="${i.severity}">${i.severity}${i.element ? ` in <b>${i.element}</b>` : ""} (line ${i.line}): ${esc(i.message)}</div>`).join("");
}
const esc = (s) => String(s).replace(/[&<>]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;" })[c]);

$("save").addEventListener("click", async () => {
  const target = $("saveas").value.trim() || name;
  $("savestate").textContent = "saving…";
  try {
    const r = await bus.call("scenario.save", { name: target, model });
    issues = r.issues; showIssues(); rebuild(); list();
    if (r.saved) { $("savestate").textContent = `saved ${r.path}`; $("savestate").className = "ok"; name = target; }
    else { $("savestate").textContent = `not saved: ${r.issues.filter((i) => i.severity === "error").length} error(s)`; $("savestate").className = "bad"; }
  } catch (e) { $("savestate").textContent = `not saved: ${e.message}`; $("savestate").className = "bad"; }
});

// ---------------------------------------------------------------- element list, JSON panel, adding
function section(key) { return (model[key] ||= []); }
function findEl(el) {
  const [kind, id] = (el || "").split(" ");
  const key = { agent: "agents", behaviour: "behaviours", volume: "volumes", trigger: "triggers" }[kind];
  return key ? [key, section(key).findIndex((x) => x.id === id)] : [null, -1];
}
function select(el) {
  selected = el;
  const [key, i] = findEl(el);
  $("json").value = key && i >= 0 ? JSON.stringify(model[key][i], null, 1) : "";
  $("selname").textContent = el || "nothing selected";
  list(); rebuild();
}
function list() {
  if (!model) return;
  const bad = badElements();
  let html = "";
  for (const [key, kind] of [["agents", "agent"], ["behaviours", "behaviour"], ["volumes", "volume"], ["triggers", "trigger"]]) {
    html += `<div class="head">${key}</div>`;
    for (const x of model[key] || []) {
      const el = `${kind} ${x.id}`;
      html += `<div class="item ${bad.has(el) ? "bad" : ""} ${selected === el ? "sel" : ""}" data-el="${esc(el)}">${esc(x.id)}</div>`;
    }
  }
  $("list").innerHTML = html;
  for (const d of $("list").querySelectorAll(".item")) d.onclick = () => { select(d.dataset.el); const h = handles().find((h) => h.el === d.dataset.el); if (h) { top.cx = h.xy[0]; top.cy = h.xy[1]; redraw(); } };
}
$("apply").addEventListener("click", () => {
  const [key, i] = findEl(selected || "");
  if (!key || i < 0) return;
  try { model[key][i] = JSON.parse($("json").value); $("jsonerr").textContent = ""; select(`${selected.split(" ")[0]} ${model[key][i].id}`); changed(); }
  catch (e) { $("jsonerr").textContent = e.message; }
});
function freshId(key, stem) { let n = 1; while (section(key).some((x) => x.id === `${stem}${n}`)) n++; return `${stem}${n}`; }
$("addagent").addEventListener("click", () => {
  const id = freshId("agents", "ped_new");
  section("agents").push({ id, kind: "pedestrian", model: "ped_adult_m1", start: [r2(top.cx), r2(top.cy)], yaw_deg: 0 });
  select(`agent ${id}`); changed();
});
$("addwp").addEventListener("click", () => {
  const [key, i] = findEl(selected || "");
  let b = null;
  if (key === "behaviours") b = model.behaviours[i];
  else if (key === "agents") {
    const a = model.agents[i];
    b = section("behaviours").find((x) => x.agent === a.id);
    if (!b) { b = { id: `${a.id}_walk`, agent: a.id, path: [] }; model.behaviours.push(b); }
  }
  if (!b) return;
  const last = b.path.length ? b.path[b.path.length - 1].to : model.agents.find((a) => a.id === b.agent).start;
  b.path.push({ to: [r2(last[0] + 3), r2(last[1])], speed: 1.4 });
  select(`behaviour ${b.id}`); changed();
});
$("addvol").addEventListener("click", () => {
  const id = freshId("volumes", "zone");
  section("volumes").push({ id, type: "box", center: [r2(top.cx), r2(top.cy)], yaw_deg: 0, size: [4, 4, 3] });
  select(`volume ${id}`); changed();
});
$("addtrig").addEventListener("click", () => {
  const id = freshId("triggers", "trigger");
  const vol = (selected || "").startsWith("volume ") ? selected.split(" ")[1] : (model.volumes || [])[0]?.id;
  const beh = (model.behaviours || [])[0]?.id;
  section("triggers").push({ id, when: { type: "enter", volume: vol }, actions: beh ? [{ type: "start", behaviour: beh }] : [{ type: "emit", event: id }] });
  select(`trigger ${id}`); changed();
});

// ---------------------------------------------------------------- loading
async function load(n) {
  const r = await bus.call("scenario.load", { name: n });
  name = r.name; model = r.model; selected = null; issues = []; preview = null; previewGroup.clear();
  $("saveas").value = name; $("savestate").textContent = "";
  const a = (model.agents || [])[0] || (model.volumes || [])[0];
  const xy = a ? (a.start || a.center || a.points[0]) : site.route[0];
  top.cx = xy[0]; top.cy = xy[1];
  orbit.target.set(xy[0], xy[1], 0); cam3.position.set(xy[0] - 40, xy[1] - 40, 35); orbit.update();
  select(null); changed();
}
$("scenario").addEventListener("change", () => load($("scenario").value));

// ---------------------------------------------------------------- preview on the lab twin
$("preview").addEventListener("click", async () => {
  $("previewstate").textContent = "running the lab twin…";
  try {
    preview = await bus.call("scenario.preview", { name, model, duration_s: Number($("pdur").value) || 120 });
    $("slider").max = preview.duration_s; $("slider").value = 0; $("slider").disabled = false;
    $("previewstate").textContent = `${preview.events.length} scenario events in ${preview.duration_s} s`;
    showPreview(0);
  } catch (e) { $("previewstate").textContent = `preview failed: ${e.message}`; }
});
function nearest(arr, t) {
  let lo = 0, hi = arr.length - 1;
  while (lo < hi) { const m = (lo + hi) >> 1; if (arr[m][0] < t) lo = m + 1; else hi = m; }
  return arr[lo];
}
function showPreview(t) {
  redraw();
  previewGroup.clear();
  if (!preview || !preview.car.length) return;
  const [, x, y, yaw] = nearest(preview.car, t);
  const car = carBox(site.vehicle, 0xff5050);
  car.position.set(x, y, cloud.ground(x, y)); car.rotation.z = yaw;
  previewGroup.add(car);
  if (preview.agents.length) {
    for (const [, ax, ay, ayaw, anim, kind] of nearest(preview.agents, t)[1]) {
      const f = agentFigure(kind); f.position.set(ax, ay, cloud.ground(ax, ay)); f.rotation.z = ayaw;
      f.userData.material.color.setHex(0xff80ff); previewGroup.add(f);
    }
  }
  const ev = preview.events.filter((e) => e[0] <= t).slice(-3).map((e) => `${e[0].toFixed(1)} s ${e[1]} ${e[2]}`).join(" · ");
  $("ptime").textContent = `t = ${t.toFixed(1)} s  ${ev}`;
}
$("slider").addEventListener("input", () => showPreview(Number($("slider").value)));

// ---------------------------------------------------------------- drawing
let dirty = true;               // redraw only after something changed
const redraw = () => { dirty = true; };
orbit.addEventListener("change", redraw);
window.addEventListener("resize", redraw);
function frame() {
  requestAnimationFrame(frame);
  if (!dirty) return;
  dirty = false;
  for (const [r, c] of [[r3, $("v3d")], [rTop, $("vtop")]]) {
    const w = c.clientWidth, h = c.clientHeight;
    if (c.width !== Math.round(w * devicePixelRatio) || c.height !== Math.round(h * devicePixelRatio)) r.setSize(w, h, false);
  }
  cam3.aspect = $("v3d").clientWidth / $("v3d").clientHeight; cam3.updateProjectionMatrix();
  placeTop();
  r3.render(scene, cam3);
  rTop.render(scene, camTop);
}

loadSite().then(async (s) => {
  site = s;
  scene.add(siteObjects(s));
  $("scenario").innerHTML = s.scenarios.map((n) => `<option>${esc(n)}</option>`).join("");
  frame();
  // the services arrive with the connection
  for (let i = 0; i < 100 && !bus.services["scenario.load"]; i++) await new Promise((r) => setTimeout(r, 100));
  const want = new URLSearchParams(location.search).get("scenario") || s.scenarios[0];
  $("scenario").value = want;
  await load(want);
});
loadCloud().then((c) => { cloud = c; scene.add(cloudPoints(c.points, 0.25)); rebuild(); });

// for tests: where a handle is in the top-down canvas (CSS pixels), and the editor's state
window.__editor = {
  handleAt: (key) => { const h = handles().find((x) => x.key === key); return h ? mapToTop(h.xy[0], h.xy[1]) : null; },
  dbg: () => JSON.stringify({services: bus.services, connected: bus.connected, site: !!site}),
  mpp: () => top.mpp, model: () => model, issues: () => issues, checking: () => $("checkstate").textContent,
};
