// The bus as pages see it: a Foxglove-protocol client (@foxglove/ws-protocol) on the
// bridge's /ws/PAGE, newest message per topic, each with its age on the bridge's clock.
import { FoxgloveClient } from "@foxglove/ws-protocol";

export class Bus {
  constructor(page, topics) {
    this.page = page;
    this.topics = new Set(topics);
    this.handlers = {};
    this.latest = {};          // topic -> {msg, rxMs}
    this.offsetMs = null;      // bridge clock - this clock (max over time messages: least delayed)
    this.calls = new Map();
    this.callId = 1;
    this.services = {};
    this.connected = false;
    this.onStatus = () => {};
    this.connect();
  }

  connect() {
    // ?ws=HOST:PORT points the page at another Foxglove-protocol server (make bench-webui's baseline)
    const other = this.page === "operator" ? new URLSearchParams(location.search).get("ws") : null;
    const url = other ? `ws://${other}/` : `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/${this.page}`;
    // foxglove-sdk's own server names the same protocol foxglove.sdk.v1
    const protocols = other ? [FoxgloveClient.SUPPORTED_SUBPROTOCOL, "foxglove.sdk.v1"] : [FoxgloveClient.SUPPORTED_SUBPROTOCOL];
    const client = new FoxgloveClient({ ws: new WebSocket(url, protocols) });
    this.client = client;
    const subs = new Map();    // subscription id -> topic
    const dec = new TextDecoder();
    client.on("open", () => { this.connected = true; this.onStatus(); });
    client.on("close", () => {
      this.connected = false; this.onStatus();
      setTimeout(() => this.connect(), 1000);
    });
    client.on("error", () => {});
    client.on("advertise", (channels) => {
      for (const ch of channels) {
        if (this.topics.has(ch.topic) && ![...subs.values()].includes(ch.topic)) {
          subs.set(client.subscribe(ch.id), ch.topic);
        }
      }
    });
    client.on("time", (ev) => {
      const off = Number(ev.timestamp) / 1e6 - Date.now();
      // the least delayed time message gives the offset; forget slowly so clock steps are followed
      this.offsetMs = this.offsetMs === null ? off : Math.max(off, this.offsetMs - 1);
    });
    client.on("message", (ev) => {
      const topic = subs.get(ev.subscriptionId);
      if (!topic) return;
      const msg = JSON.parse(dec.decode(ev.data));
      const rxMs = Number(ev.timestamp) / 1e6;
      this.latest[topic] = { msg, rxMs };
      for (const fn of this.handlers[topic] || []) fn(msg, rxMs);
    });
    client.on("advertiseServices", (services) => {
      for (const s of services) this.services[s.name] = s.id;
    });
    client.on("serviceCallResponse", (ev) => {
      const p = this.calls.get(ev.callId);
      if (p) { this.calls.delete(ev.callId); p.resolve(JSON.parse(dec.decode(ev.data))); }
    });
    client.on("serviceCallFailure", (ev) => {
      const p = this.calls.get(ev.callId);
      if (p) { this.calls.delete(ev.callId); p.reject(new Error(ev.message)); }
    });
    client.on("status", (ev) => console.warn("bridge:", ev.message));
  }

  on(topic, fn) { (this.handlers[topic] ||= []).push(fn); }

  // Age (s) of the newest message of a topic, on the bridge's clock; null if none.
  age(topic) {
    const l = this.latest[topic];
    if (!l) return null;
    return (Date.now() + (this.offsetMs ?? 0) - l.rxMs) / 1000;
  }

  advertise(topic) {
    return this.client.advertise({ topic, encoding: "json", schemaName: "portobello." + topic.toLowerCase() });
  }

  send(channelId, obj) {
    this.client.sendMessage(channelId, new TextEncoder().encode(JSON.stringify(obj)));
  }

  call(name, request) {
    const serviceId = this.services[name];
    if (!serviceId) return Promise.reject(new Error(`service ${name} not offered to this page`));
    const callId = this.callId++;
    return new Promise((resolve, reject) => {
      this.calls.set(callId, { resolve, reject });
      this.client.sendServiceCallRequest({ serviceId, callId, encoding: "json",
        data: new TextEncoder().encode(JSON.stringify(request)) });
    });
  }
}

export async function loadSite() {
  const r = await fetch("/api/site");
  return r.json();
}

// The thinned prior map and its ground grid (see sitedata.py for the layout).
export async function loadCloud() {
  for (let i = 0; i < 60; i++) {
    const r = await fetch("/api/cloud.bin");
    if (r.ok) {
      const buf = await r.arrayBuffer();
      const dv = new DataView(buf);
      const n = dv.getUint32(0, true);
      const pts = new Float32Array(buf, 4, n * 3);
      let o = 4 + n * 12;
      const nx = dv.getUint32(o, true), ny = dv.getUint32(o + 4, true);
      const x0 = dv.getFloat32(o + 8, true), y0 = dv.getFloat32(o + 12, true), cell = dv.getFloat32(o + 16, true);
      const grid = new Float32Array(buf.slice(o + 20, o + 20 + nx * ny * 4));
      const ground = (x, y) => {
        const ix = Math.floor((x - x0) / cell), iy = Math.floor((y - y0) / cell);
        if (ix < 0 || iy < 0 || ix >= nx || iy >= ny) return 0;
        const z = grid[iy * nx + ix];
        return Number.isFinite(z) ? z : 0;
      };
      return { points: pts, ground };
    }
    await new Promise((res) => setTimeout(res, 1000));
  }
  return { points: new Float32Array(0), ground: () => 0 };
}

export function yawOf(q) {   // q = [w, x, y, z] (map <- base)
  const [w, x, y, z] = q;
  return Math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z));
}

export const STATE_NAMES = ["STARTING", "OK", "DEGRADED", "ERROR", "STOPPING"];
export const POSE_STATUS = ["INITIALIZING", "TRACKING", "DEGRADED", "LOST"];
// Text from the bus made safe for innerHTML (names and details are set by any process).
export const esc = (s) => String(s ?? "").replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);
// command_state_t.STATE_* of SUPERVISOR, in order
export const COMMAND_STATES = ["STOPPED", "WAITING", "STARTING", "RUNNING", "BACKOFF", "STOPPING", "EXITED", "FAILED"];
