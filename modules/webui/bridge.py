#!/usr/bin/env python3
"""webui: the bridge between the LCM bus and browsers (docs/webui.md).

    webui --site SITE [--listen ADDR:PORT] [--lcm-url URL]

One port serves the pages (/operator, /participant, /editor, /view), the site data they
draw (/api/site, /api/cloud.bin) and, on /ws and /ws/PAGE, the bus over the Foxglove
WebSocket protocol (subprotocol foxglove.websocket.v1; Foxglove and Lichtblick open
ws://ADDR:PORT/ws read-only). Messages go out JSON-encoded, stamped with the time the
bridge received them (the page shows their age). Each client holds only the newest
message of each channel it subscribes to: a slow client skips messages, it never makes
a queue grow. Only /ws/participant may publish (PARTICIPANT_INPUT "proceed"); only
/ws/editor may call the scenario services, which write inside SITE/scenarios/ alone.
"""
import argparse
import asyncio
import http
import json
import math
import mimetypes
import os
import pathlib
import socket
import struct
import sys
import threading
import time

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "build" / "python"))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import lcm  # noqa: E402
import portobello  # noqa: E402
import websockets  # noqa: E402
from websockets.asyncio.server import serve  # noqa: E402
from websockets.datastructures import Headers  # noqa: E402
from websockets.http11 import Response  # noqa: E402

import sitedata  # noqa: E402
import scenario_edit  # noqa: E402

SUBPROTOCOL = "foxglove.websocket.v1"
PROJECT_LCM_URL = "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=8388608"
PAGES = ("operator", "participant", "editor", "view")
# What a page's connection may do beyond reading: publish these channels, call services.
ROLES = {
    "participant": {"publish": {"PARTICIPANT_INPUT"}, "services": False},
    "editor": {"publish": set(), "services": True},
}
PROCEED_INPUTS = {"proceed"}
TIME_PERIOD_S = 0.1        # server time to clients, for the age shown on pages
# Bytes a slow client may have in flight on our side (websockets' buffer + the kernel's send
# buffer): beyond it sends wait, and meanwhile the newest-message slots are overwritten.
WRITE_LIMIT = 16 * 1024
SNDBUF = 32 * 1024


# ---------------------------------------------------------------- LCM <-> JSON
TYPES = {cls._get_packed_fingerprint(): cls for cls in
         (getattr(portobello, n) for n in dir(portobello) if n.endswith("_t"))}


def to_plain(obj):
    """An lcm message as JSON-able data; non-finite floats become null (JSON has no NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, (list, tuple)):
        return [to_plain(v) for v in obj]
    if isinstance(obj, bytes):
        return list(obj)
    if hasattr(obj, "__slots__"):
        return {k: to_plain(getattr(obj, k)) for k in obj.__slots__}
    return obj


def json_schema(cls):
    """A JSON schema of an lcm type (for Foxglove's panels)."""
    def field(tn, dims):
        if tn in ("double", "float"):
            t = {"type": ["number", "null"]}
        elif tn in ("int8_t", "int16_t", "int32_t", "int64_t", "byte"):
            t = {"type": "integer"}
        elif tn == "boolean":
            t = {"type": "boolean"}
        elif tn == "string":
            t = {"type": "string"}
        else:
            t = json_schema(getattr(portobello, tn.split(".")[-1]))
        for _ in dims:
            t = {"type": "array", "items": t}
        return t
    props = {k: field(tn, d or []) for k, tn, d in zip(cls.__slots__, cls.__typenames__, cls.__dimensions__)}
    return {"type": "object", "title": "portobello." + cls.__name__, "properties": props}


# ---------------------------------------------------------------- clients
class Client:
    """One WebSocket connection: its subscriptions and one newest-message slot per channel."""

    def __init__(self, ws, role):
        self.ws = ws
        self.role = role
        self.subs = {}            # subscription id -> channel id
        self.latest = {}          # slot (a channel; STATUS: per module) -> (channel id, receive ns, payload)
        self.wake = asyncio.Event()
        self.published = {}       # client channel id -> topic this client may publish
        self.skipped = 0          # messages overwritten before they could be sent
        self.time_due = True      # the bridge's clock is due to this client

    def offer(self, slot, chan_id, ts_ns, payload):
        if slot in self.latest:
            self.skipped += 1
        self.latest[slot] = (chan_id, ts_ns, payload)
        self.wake.set()

    async def sender(self):
        """Sends each channel's newest message; while a send waits on a slow socket the
        slots are overwritten, so memory stays one message per channel."""
        while True:
            await self.wake.wait()
            self.wake.clear()
            if self.time_due:
                self.time_due = False
                await self.ws.send(struct.pack("<BQ", 2, time.time_ns()))
            while self.latest:
                _, (chan_id, ts, payload) = self.latest.popitem()
                for sub_id, cid in list(self.subs.items()):
                    if cid == chan_id:
                        await self.ws.send(struct.pack("<BIQ", 1, sub_id, ts) + payload)


class Bridge:
    def __init__(self, site, lcm_url, www):
        self.site = site
        self.www = www
        self.lc = lcm.LCM(lcm_url)
        self.loop = None
        self.clients = set()
        self.channels = {}        # topic -> {"id", "schemaName", ...}
        self.by_id = {}
        self.next_id = 1
        self.received = 0
        self.undecodable = {}
        self.editor = scenario_edit.Editor(site)

    # ---- bus side (LCM thread hands every message to the event loop)
    def tick_time(self):
        """Every TIME_PERIOD_S: each client is due the bridge's clock (for message ages)."""
        for c in self.clients:
            c.time_due = True
            c.wake.set()
        self.loop.call_later(TIME_PERIOD_S, self.tick_time)

    def start_lcm(self):
        self.lc.subscribe(".*", lambda ch, data: self.loop.call_soon_threadsafe(self.on_lcm, ch, data, time.time_ns()))
        self.lcm_stop = False
        threading.Thread(target=self._lcm_thread, daemon=True).start()

    def _lcm_thread(self):
        while not self.lcm_stop:
            self.lc.handle_timeout(100)

    def on_lcm(self, channel, data, rx_ns):
        self.received += 1
        cls = TYPES.get(data[:8])
        if cls is None:
            self.undecodable[channel] = self.undecodable.get(channel, 0) + 1
            return
        chan = self.channels.get(channel)
        if chan is None:
            chan = self.advertise(channel, cls)
        subscribers = [c for c in self.clients if chan["id"] in c.subs.values()]
        if not subscribers:
            return                # decoded only when someone looks
        try:
            msg = cls.decode(data)
            payload = json.dumps(to_plain(msg), separators=(",", ":")).encode()
        except Exception:         # a message that matches a fingerprint but not its layout
            self.undecodable[channel] = self.undecodable.get(channel, 0) + 1
            return
        # STATUS carries every module's heartbeat on one channel: one slot per module, so a
        # busy client never loses one module's health to another's
        slot = (chan["id"], msg.module) if cls is portobello.status_t else chan["id"]
        for c in subscribers:
            c.offer(slot, chan["id"], rx_ns, payload)

    def advertise(self, topic, cls):
        chan = {"id": self.next_id, "topic": topic, "encoding": "json", "schemaName": "portobello." + cls.__name__,
                "schema": json.dumps(json_schema(cls)), "schemaEncoding": "jsonschema"}
        self.next_id += 1
        self.channels[topic] = chan
        self.by_id[chan["id"]] = chan
        msg = json.dumps({"op": "advertise", "channels": [chan]})
        for c in self.clients:
            asyncio.ensure_future(self._send(c, msg))
        return chan

    async def _send(self, client, msg):
        try:
            await client.ws.send(msg)
        except websockets.ConnectionClosed:
            pass

    # ---- browser side
    async def handler(self, ws):
        path = ws.request.path.split("?")[0].rstrip("/")
        role = path[len("/ws/"):] if path.startswith("/ws/") else ""
        sock = ws.transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SNDBUF)
        client = Client(ws, role)
        rights = ROLES.get(role, {"publish": set(), "services": False})
        caps = ["time"] + (["clientPublish"] if rights["publish"] else []) + (["services"] if rights["services"] else [])
        await ws.send(json.dumps({"op": "serverInfo", "name": "portobello webui " + self.site.name, "capabilities": caps,
                                  "supportedEncodings": ["json"] if rights["publish"] or rights["services"] else [],
                                  "metadata": {"site": self.site.name, "role": role or "read-only"},
                                  "sessionId": str(os.getpid())}))
        await ws.send(json.dumps({"op": "advertise", "channels": list(self.channels.values())}))
        if rights["services"]:
            await ws.send(json.dumps({"op": "advertiseServices", "services": scenario_edit.SERVICES}))
        self.clients.add(client)
        sender = asyncio.ensure_future(client.sender())
        try:
            async for msg in ws:
                if isinstance(msg, str):
                    await self.on_text(client, rights, msg)
                else:
                    await self.on_binary(client, rights, msg)
        except websockets.ConnectionClosed:
            pass
        finally:
            self.clients.discard(client)
            sender.cancel()

    async def status(self, client, level, text):
        await self._send(client, json.dumps({"op": "status", "level": level, "message": text}))

    async def on_text(self, client, rights, text):
        try:
            msg = json.loads(text)
            op = msg["op"]
        except (ValueError, KeyError, TypeError):
            return await self.status(client, 2, "not a protocol message")
        if op == "subscribe":
            for s in msg.get("subscriptions", []):
                if s.get("channelId") in self.by_id:
                    client.subs[int(s["id"])] = s["channelId"]
        elif op == "unsubscribe":
            for sid in msg.get("subscriptionIds", []):
                client.subs.pop(sid, None)
        elif op == "advertise":
            for ch in msg.get("channels", []):
                topic = ch.get("topic")
                if topic in rights["publish"] and ch.get("encoding") == "json":
                    client.published[ch["id"]] = topic
                else:
                    await self.status(client, 2, f"publishing {topic!r} is not allowed from this page")
        elif op == "unadvertise":
            for cid in msg.get("channelIds", []):
                client.published.pop(cid, None)

    async def on_binary(self, client, rights, data):
        if len(data) >= 5 and data[0] == 1:                      # client message data
            cid = struct.unpack_from("<I", data, 1)[0]
            topic = client.published.get(cid)
            if topic is None:
                return await self.status(client, 2, f"client channel {cid} was not advertised or not allowed")
            err = self.publish_input(topic, data[5:])
            if err:
                await self.status(client, 2, err)
        elif len(data) >= 13 and data[0] == 2 and rights["services"]:   # service call
            sid, call_id, elen = struct.unpack_from("<III", data, 1)
            enc = data[13:13 + elen].decode()
            body = data[13 + elen:]
            try:
                result = await self.editor.call(sid, json.loads(body))
                out = json.dumps(result).encode()
                await client.ws.send(struct.pack("<BIII", 3, sid, call_id, len(enc)) + enc.encode() + out)
            except Exception as e:  # noqa: BLE001 -- the error goes back to the page, named
                await self._send(client, json.dumps({"op": "serviceCallFailure", "serviceId": sid, "callId": call_id,
                                                     "message": str(e)}))
        else:
            await self.status(client, 2, "binary operation not allowed from this page")

    def publish_input(self, topic, payload):
        """PARTICIPANT_INPUT from the phone: the press time is the bridge's clock minus how long
        ago the page says the press was (phone clocks are not trusted)."""
        try:
            m = json.loads(payload)
            name, value = m["input"], int(m.get("value", 1))
            ago_ms = float(m.get("sent_ms", 0)) - float(m.get("press_ms", 0))
        except (ValueError, KeyError, TypeError):
            return f"{topic}: expected JSON {{input, value, press_ms, sent_ms}}"
        if name not in PROCEED_INPUTS:
            return f"{topic}: input {name!r} is not allowed (allowed: {sorted(PROCEED_INPUTS)})"
        msg = portobello.participant_input_t()
        msg.utime = time.time_ns() // 1000 - int(min(max(ago_ms, 0.0), 5000.0) * 1000)
        msg.input = name
        msg.device = "phone"
        msg.value = value
        self.lc.publish(topic, msg.encode())
        return None

    # ---- HTTP side: pages, bundles, site data
    def http(self, connection, request):
        path = request.path.split("?")[0]
        if path.startswith("/ws"):
            # pages that write are served only to pages of this bridge (not to a web site the
            # phone happens to visit); read-only /ws stays open to Foxglove's and Lichtblick's apps
            origin = request.headers.get("Origin")
            host = request.headers.get("Host", "")
            writes = path.rstrip("/")[len("/ws/"):] in ROLES
            if writes and origin and origin.split("://", 1)[-1] != host:
                return self._response(403, b"cross-origin WebSocket refused for a page that writes\n", "text/plain")
            return None
        if path in ("", "/"):
            return self._response(200, self._index(), "text/html")
        name = path.strip("/")
        if name in PAGES:
            return self._file(self.www / f"{name}.html")
        if name == "api/site":
            return self._response(200, json.dumps(self.site.summary()).encode(), "application/json")
        if name == "api/cloud.bin":
            cloud = self.site.cloud_if_ready()
            if cloud is None:       # still being thinned (a few seconds after start): the page retries
                return self._response(503, b"map cloud not ready\n", "text/plain")
            return self._response(200, cloud, "application/octet-stream")
        if name.startswith("static/") and "/" not in name[7:] and not name[7:].startswith("."):
            return self._file(self.www / name[7:])
        return self._response(404, b"not found\n", "text/plain")

    def _index(self):
        links = "".join(f'<li><a href="/{p}">/{p}</a></li>' for p in PAGES)
        return f"<!doctype html><title>Portobello</title><h1>Portobello: {self.site.name}</h1><ul>{links}</ul>".encode()

    def _file(self, p):
        if not p.is_file():
            return self._response(404, f"{p.name} not built (run make)\n".encode(), "text/plain")
        return self._response(200, p.read_bytes(), mimetypes.guess_type(p.name)[0] or "application/octet-stream")

    @staticmethod
    def _response(code, body, ctype):
        return Response(code, http.HTTPStatus(code).phrase,
                        Headers([("Content-Type", ctype), ("Content-Length", str(len(body))),
                                 ("Cache-Control", "no-cache")]), body)


async def amain(args):
    site = sitedata.Site(args.site)
    bridge = Bridge(site, args.lcm_url, pathlib.Path(args.www))
    bridge.loop = asyncio.get_running_loop()
    threading.Thread(target=site.cloud_bytes, daemon=True).start()   # thinning the map takes seconds
    bridge.start_lcm()
    bridge.tick_time()
    host, port = args.listen.rsplit(":", 1)
    async with serve(bridge.handler, host, int(port), process_request=bridge.http, subprotocols=[SUBPROTOCOL],
                     max_size=4 * 1024 * 1024, compression=None, write_limit=WRITE_LIMIT) as server:
        print(f"webui: site {site.name}: http://{args.listen}/operator /participant /editor /view; "
              f"bus on ws://{args.listen}/ws (Foxglove protocol)", flush=True)
        stop = asyncio.Event()
        import signal
        for sig in (signal.SIGINT, signal.SIGTERM):
            bridge.loop.add_signal_handler(sig, stop.set)
        await stop.wait()
        server.close()
    bridge.lcm_stop = True


def main():
    ap = argparse.ArgumentParser(prog="webui", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--site", default=str(ROOT / "maps" / "default"), help="site folder (default maps/default)")
    ap.add_argument("--listen", default="127.0.0.1:8080",
                    help="ADDR:PORT (default 127.0.0.1:8080: this machine only; 0.0.0.0:8080 for phones on the car's Wi-Fi)")
    ap.add_argument("--lcm-url", default=os.environ.get("LCM_DEFAULT_URL", PROJECT_LCM_URL), help="LCM bus")
    ap.add_argument("--www", default=str(ROOT / "build" / "webui"), help="built pages (default build/webui)")
    args = ap.parse_args()
    try:
        sitedata.Site(args.site)
    except sitedata.SiteError as e:
        print(f"webui: {e}", file=sys.stderr)
        return 1
    if ":" not in args.listen:
        print(f"webui: --listen {args.listen}: expected ADDR:PORT", file=sys.stderr)
        return 2
    asyncio.run(amain(args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
