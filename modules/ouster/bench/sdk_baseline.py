"""Baseline for make bench-ouster: ouster-sdk (PyPI) assembling the same capture's packets
into frames with its C++ FrameBatcher, called from Python as its users do. Prints JSON:
median thread CPU time per frame (us). Run with a Python that has ouster-sdk installed."""
import json
import statistics
import sys
import time
import warnings

warnings.simplefilter("ignore")
import ouster.sdk.core as core                      # noqa: E402
from ouster.sdk.pcap import PcapPacketSource        # noqa: E402

pcap, meta, frames = sys.argv[1], sys.argv[2], int(sys.argv[3])
info = core.SensorInfo(open(meta).read())
packets = []
for item in PcapPacketSource(pcap, sensor_info=[info]):
    p = item[1] if isinstance(item, tuple) else item
    if isinstance(p, core.LidarPacket):
        packets.append(p)
legacy = str(info.format.udp_profile_lidar).endswith("LEGACY")
cols_per_packet, rows = info.format.columns_per_packet, info.format.pixels_per_column
col_size = 16 + rows * 12 + 4
batcher = core.FrameBatcher(info)
frame = core.LidarFrame(info)
times, complete, fid = [], 0, 1000
for f in range(frames):
    fid = (fid + 1) & 0xFFFF
    for p in packets:        # next frame: new frame_id (outside the timing)
        b = p.buf
        if legacy:
            for k in range(cols_per_packet):
                b[k * col_size + 10], b[k * col_size + 11] = fid & 0xFF, fid >> 8
        else:
            b[2], b[3] = fid & 0xFF, fid >> 8
    t0 = time.thread_time_ns()
    for p in packets:
        if batcher.batch(p, frame):
            complete += 1
    times.append((time.thread_time_ns() - t0) / 1000)
print(json.dumps({"sdk_batch_us": statistics.median(times), "frames": frames, "complete": complete,
                  "frame_id": int(frame.frame_id)}))
