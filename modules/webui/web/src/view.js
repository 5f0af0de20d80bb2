// /view: the reference renderer. First-person from the driver's eye (HEAD_POSE when the
// headset tracks, else a default eye point) with the car's own body as a cutout that
// hides virtual agents behind it, and a chase view inset. Agents beyond the render
// distance (in_render_range false, 45 m by default) are not drawn.
import * as THREE from "three";
import { Bus, loadSite, loadCloud } from "./bus.js";
import { makeRenderer, cloudPoints, siteObjects, agentFigure, carBox, lights } from "./scene.js";

const DEFAULT_EYE = [1.05, 0.37, 1.20];   // base frame: driver's eye in a Prius-sized car (m)
const bus = new Bus("view", ["POSE_PREDICTED", "POSE", "AGENTS", "HEAD_POSE"]);
const canvas = document.getElementById("view");
const info = document.getElementById("info");
const renderer = makeRenderer(canvas);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x9fb8d0);
scene.fog = new THREE.Fog(0x9fb8d0, 60, 160);
lights(scene);
const ground = new THREE.Mesh(new THREE.PlaneGeometry(2000, 2000), new THREE.MeshLambertMaterial({ color: 0x4a4f55 }));
ground.position.z = -0.02;
scene.add(ground);
const fp = new THREE.PerspectiveCamera(70, 1, 0.05, 500);
const chase = new THREE.PerspectiveCamera(55, 1, 0.1, 1000);
fp.up.set(0, 0, 1); chase.up.set(0, 0, 1);
let site = null, car = null, cutout = null;
const figures = new Map();

// The car's body seen from inside: hood, dashboard and A-pillars, drawn black over
// anything virtual behind them (the seed's cutout of the ego car).
function cutoutOf(v) {
  const g = new THREE.Group();
  const mat = new THREE.MeshBasicMaterial({ color: 0x050505 });
  const front = v.length - v.rear_overhang;
  const box = (x0, x1, y0, y1, z0, z1) => {
    const m = new THREE.Mesh(new THREE.BoxGeometry(x1 - x0, y1 - y0, z1 - z0), mat);
    m.position.set((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2);
    g.add(m);
  };
  box(1.75, front, -v.width / 2, v.width / 2, 0.2, 0.92);        // hood
  box(1.45, 1.75, -v.width / 2, v.width / 2, 0.2, 0.95);         // dashboard
  for (const s of [-1, 1]) {                                       // A-pillars, leaning back
    const p = new THREE.Mesh(new THREE.BoxGeometry(0.06, 0.06, 0.62), mat);
    p.position.set(1.55, s * (v.width / 2 - 0.08), 1.28);
    p.rotation.y = -0.9;
    g.add(p);
  }
  box(0.9, 1.45, -v.width / 2, v.width / 2, 1.42, 1.47);         // roof edge
  return g;
}

function resize() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  renderer.setSize(w, h, false);
  fp.aspect = w / h; fp.updateProjectionMatrix();
  chase.aspect = 4 / 3; chase.updateProjectionMatrix();
}

function update() {
  const p = (bus.latest.POSE_PREDICTED || bus.latest.POSE)?.msg;
  if (p && car) {
    const [w, x, y, z] = p.orientation;
    const q = new THREE.Quaternion(x, y, z, w);
    const pos = new THREE.Vector3(...p.position);
    car.position.copy(pos); car.quaternion.copy(q);
    cutout.position.copy(pos); cutout.quaternion.copy(q);
    const head = bus.latest.HEAD_POSE?.msg;
    const useHead = head && head.tracking && bus.age("HEAD_POSE") < 0.5;
    const eyeB = new THREE.Vector3(...(useHead ? head.position : DEFAULT_EYE));
    let qEye = q.clone();
    if (useHead) { const [hw, hx, hy, hz] = head.orientation; qEye = q.clone().multiply(new THREE.Quaternion(hx, hy, hz, hw)); }
    const eye = eyeB.applyQuaternion(q).add(pos);
    fp.position.copy(eye);
    fp.up.copy(new THREE.Vector3(0, 0, 1).applyQuaternion(qEye));
    fp.lookAt(eye.clone().add(new THREE.Vector3(1, 0, 0).applyQuaternion(qEye)));
    const back = new THREE.Vector3(-9, 0, 4).applyQuaternion(q).add(pos);
    chase.position.copy(back);
    chase.lookAt(new THREE.Vector3(3, 0, 0.5).applyQuaternion(q).add(pos));
  }
  const am = bus.latest.AGENTS?.msg;
  const seen = new Set();
  let drawn = 0;
  for (const a of am ? am.agents : []) {
    let f = figures.get(a.id);
    if (!f) { f = agentFigure(a.kind); figures.set(a.id, f); scene.add(f); }
    f.position.set(...a.position);
    f.rotation.z = a.yaw_rad;
    // a little gait so walking reads as walking
    f.position.z += a.animation === "walk" ? 0.04 * Math.abs(Math.sin(a.animation_phase * 2 * Math.PI)) : 0;
    f.visible = a.in_render_range;
    drawn += f.visible;
    seen.add(a.id);
  }
  for (const [id, f] of figures) if (!seen.has(id)) { scene.remove(f); figures.delete(id); }
  const age = bus.age("AGENTS");
  info.textContent = `${p ? "" : "no pose · "}${drawn} of ${am ? am.agents.length : 0} agents in range · ` +
    `AGENTS ${age === null ? "none" : (age * 1000).toFixed(0) + " ms old"} · pose ${bus.age("POSE_PREDICTED") !== null ? "POSE_PREDICTED" : "POSE"}`;
}

let dirty = true;        // draw when something new arrived, not 60 times a second for nothing
for (const t of ["POSE_PREDICTED", "POSE", "AGENTS", "HEAD_POSE"]) bus.on(t, () => { dirty = true; });
function frame() {
  requestAnimationFrame(frame);
  if (!dirty) return;
  dirty = false;
  update();
  const w = canvas.clientWidth, h = canvas.clientHeight;
  renderer.setScissorTest(true);
  cutout.visible = true; car.visible = false;
  renderer.setViewport(0, 0, w, h); renderer.setScissor(0, 0, w, h);
  renderer.render(scene, fp);
  const cw = Math.round(w * 0.3), ch = Math.round(cw * 3 / 4);
  cutout.visible = false; car.visible = true;
  renderer.setViewport(w - cw - 10, 10, cw, ch); renderer.setScissor(w - cw - 10, 10, cw, ch);
  renderer.render(scene, chase);
}

loadSite().then((s) => {
  site = s;
  scene.add(siteObjects(s));
  car = carBox(s.vehicle); cutout = cutoutOf(s.vehicle);
  scene.add(car, cutout);
  // before the first pose: stand at the route's start, facing along it
  const [a, b] = [s.route[0], s.route[1]];
  const yaw = Math.atan2(b[1] - a[1], b[0] - a[0]);
  const q = new THREE.Quaternion().setFromAxisAngle(new THREE.Vector3(0, 0, 1), yaw);
  car.position.set(a[0], a[1], 0); car.quaternion.copy(q);
  cutout.position.copy(car.position); cutout.quaternion.copy(q);
  fp.position.set(...DEFAULT_EYE).applyQuaternion(q).add(car.position);
  fp.lookAt(fp.position.clone().add(new THREE.Vector3(1, 0, 0).applyQuaternion(q)));
  chase.position.copy(new THREE.Vector3(-9, 0, 4).applyQuaternion(q).add(car.position));
  chase.lookAt(car.position);
  resize();
  frame();
});
loadCloud().then((c) => { scene.add(cloudPoints(c.points, 0.12)); dirty = true; });
window.addEventListener("resize", () => { resize(); dirty = true; });
