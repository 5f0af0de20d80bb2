// /participant: the phone. "Is now safe to proceed?" while the car waits at a stop line
// (LAB_EVENT awaiting_proceed, or lab_vehicle's STATUS gauge); one big Proceed button
// that publishes PARTICIPANT_INPUT once per press.
import { Bus } from "./bus.js";

const DEBOUNCE_MS = 600;   // a second press within this is the same press (bouncing fingers)
const bus = new Bus("participant", ["LAB_EVENT", "STATUS"]);
const prompt = document.getElementById("prompt");
const button = document.getElementById("proceed");
const info = document.getElementById("info");
let channel = null;
let lastPress = -Infinity;
let awaitingEvent = null;   // {awaiting, rxMs}
let awaitingGauge = null;
let presses = 0;

bus.onStatus = () => {
  channel = bus.connected ? bus.advertise("PARTICIPANT_INPUT") : null;   // again after a reconnect
  render();
};

bus.on("LAB_EVENT", (m, rxMs) => {
  if (m.event_id === "awaiting_proceed") awaitingEvent = { awaiting: true, rxMs };
  else if (["proceed", "departed", "finished"].includes(m.event_id)) awaitingEvent = { awaiting: false, rxMs };
  render();
});
bus.on("STATUS", (m, rxMs) => {
  if (m.module !== "lab_vehicle") return;
  const i = m.counter_names.indexOf("awaiting_proceed");
  if (i >= 0) awaitingGauge = { awaiting: m.counter_values[i] > 0, rxMs };
  render();
});

function awaiting() {
  const a = [awaitingEvent, awaitingGauge].filter(Boolean).sort((p, q) => q.rxMs - p.rxMs)[0];
  return a ? a.awaiting : false;
}

function press(ev) {
  ev.preventDefault();
  const now = Date.now();
  if (now - lastPress < DEBOUNCE_MS || !bus.connected || channel === null) return;
  lastPress = now;
  presses++;
  bus.send(channel, { input: "proceed", value: 1, press_ms: now, sent_ms: Date.now() });
  button.classList.add("sent");
  setTimeout(() => button.classList.remove("sent"), 400);
  render();
}
button.addEventListener("pointerdown", press);
window.addEventListener("keydown", (ev) => { if ((ev.key === " " || ev.key === "Enter") && !ev.repeat) press(ev); });

function render() {
  const a = awaiting();
  prompt.textContent = a ? "Is now safe to proceed?" : "Please wait";
  prompt.className = a ? "ask" : "wait";
  button.className = a ? "ready" : "";
  const age = bus.age("STATUS");
  info.textContent = (bus.connected ? "connected" : "not connected") +
    (age === null ? " · no car status yet" : ` · car status ${age.toFixed(1)} s old`) + ` · presses ${presses}`;
}
setInterval(render, 500);
render();
window.__participant = { presses: () => presses };
