#!/usr/bin/env python3
"""Baseline for make bench-webui: the same LCM -> JSON relay as the webui bridge, served by
foxglove-sdk's WebSocket server (its per-client FIFO backlog instead of our newest message
per channel). Usage: sdk_relay.py LCM_URL PORT"""
import json
import pathlib
import sys
import threading
import time

ROOT = pathlib.Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "build" / "python"))
sys.path.insert(0, str(ROOT / "modules" / "webui"))

import foxglove  # noqa: E402
import lcm  # noqa: E402
from bridge import TYPES, json_schema, to_plain  # noqa: E402


def main():
    url, port = sys.argv[1], int(sys.argv[2])
    server = foxglove.start_server(host="127.0.0.1", port=port, name="sdk baseline")
    channels = {}
    lock = threading.Lock()

    def on(ch, data):
        rx = time.time_ns()
        cls = TYPES.get(data[:8])
        if cls is None:
            return
        with lock:
            if ch not in channels:
                schema = foxglove.Schema(name="portobello." + cls.__name__, encoding="jsonschema",
                                         data=json.dumps(json_schema(cls)).encode())
                channels[ch] = foxglove.Channel(ch, message_encoding="json", schema=schema)
        channels[ch].log(json.dumps(to_plain(cls.decode(data)), separators=(",", ":")).encode(), log_time=rx)

    lc = lcm.LCM(url)
    lc.subscribe(".*", on)
    print(f"sdk relay on ws://127.0.0.1:{port}", flush=True)
    try:
        while True:
            lc.handle_timeout(100)
    except KeyboardInterrupt:
        server.stop()


if __name__ == "__main__":
    main()
