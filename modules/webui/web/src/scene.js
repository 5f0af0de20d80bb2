// three.js pieces shared by /editor and /view: the map frame is used as the world frame
// (z up: camera.up = +z), the thinned prior map, route, crosswalks, agent figures.
import * as THREE from "three";

export function makeRenderer(canvas) {
  const r = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  r.setPixelRatio(devicePixelRatio);
  r.setClearColor(0x15181c);
  return r;
}

export function cloudPoints(points, size = 0.25) {
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.BufferAttribute(points, 3));
  const colours = new Float32Array(points.length);
  for (let i = 0; i < points.length; i += 3) {       // height colour ramp: ground grey-blue, walls lighter
    const t = Math.max(0, Math.min(1, points[i + 2] / 6));
    colours[i] = 0.30 + 0.45 * t; colours[i + 1] = 0.35 + 0.40 * t; colours[i + 2] = 0.45 + 0.25 * t;
  }
  g.setAttribute("color", new THREE.BufferAttribute(colours, 3));
  return new THREE.Points(g, new THREE.PointsMaterial({ size, vertexColors: true, sizeAttenuation: true }));
}

export function siteObjects(site, ground = () => 0) {
  const group = new THREE.Group();
  const route = site.route.map(([x, y]) => new THREE.Vector3(x, y, ground(x, y) + 0.05));
  route.push(route[0].clone());
  group.add(new THREE.Line(new THREE.BufferGeometry().setFromPoints(route), new THREE.LineBasicMaterial({ color: 0xe0c060 })));
  for (const cw of site.crosswalks) {
    const m = new THREE.Mesh(new THREE.PlaneGeometry(cw.width, cw.length),
      new THREE.MeshBasicMaterial({ color: 0xdddddd, transparent: true, opacity: 0.35, side: THREE.DoubleSide }));
    m.position.set(cw.center[0], cw.center[1], ground(cw.center[0], cw.center[1]) + 0.04);
    m.rotation.z = cw.yaw_deg * Math.PI / 180;
    group.add(m);
  }
  for (const sl of site.stop_lines) {
    const m = new THREE.Mesh(new THREE.PlaneGeometry(0.4, site.lane_width), new THREE.MeshBasicMaterial({ color: 0xffffff, side: THREE.DoubleSide }));
    m.position.set(sl.xy[0], sl.xy[1], ground(sl.xy[0], sl.xy[1]) + 0.06);
    m.rotation.z = sl.yaw_deg * Math.PI / 180;
    group.add(m);
  }
  return group;
}

export const KIND_COLOUR = { pedestrian: 0xffb020, cyclist: 0x33d6c4, vehicle: 0xc084fc, object: 0xa3a3a3 };

// A simple figure: pedestrians a body and a head, others a box; +x is the figure's front.
export function agentFigure(kind) {
  const mat = new THREE.MeshLambertMaterial({ color: KIND_COLOUR[kind] ?? 0xffffff });
  const g = new THREE.Group();
  if (kind === "pedestrian") {
    const body = new THREE.Mesh(new THREE.CylinderGeometry(0.22, 0.25, 1.4, 12), mat);
    body.rotation.x = Math.PI / 2; body.position.z = 0.7;
    const head = new THREE.Mesh(new THREE.SphereGeometry(0.14, 12, 8), mat);
    head.position.z = 1.6;
    const nose = new THREE.Mesh(new THREE.BoxGeometry(0.15, 0.06, 0.06), mat);
    nose.position.set(0.15, 0, 1.6);
    g.add(body, head, nose);
  } else {
    const size = kind === "vehicle" ? [4.4, 1.8, 1.5] : kind === "cyclist" ? [1.8, 0.5, 1.7] : [0.6, 0.6, 0.9];
    const box = new THREE.Mesh(new THREE.BoxGeometry(...size), mat);
    box.position.z = size[2] / 2;
    g.add(box);
  }
  g.userData.material = mat;
  return g;
}

export function carBox(vehicle, color = 0xe23b3b) {
  const g = new THREE.Group();
  const m = new THREE.Mesh(new THREE.BoxGeometry(vehicle.length, vehicle.width, vehicle.height),
    new THREE.MeshLambertMaterial({ color }));
  m.position.set(vehicle.length / 2 - vehicle.rear_overhang, 0, vehicle.height / 2);
  g.add(m);
  return g;
}

export function lights(scene) {
  scene.add(new THREE.AmbientLight(0xffffff, 0.6));
  const d = new THREE.DirectionalLight(0xffffff, 1.2);
  d.position.set(30, -20, 60);
  scene.add(d);
}
