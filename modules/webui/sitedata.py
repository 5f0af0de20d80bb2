"""The site as the pages draw it: route, stop lines, crosswalks, scenario names, and the
prior map thinned to a point cloud a browser renders smoothly, with a ground-height grid
that editor drags snap to."""
import pathlib
import struct
import sys
import threading

import numpy as np
import yaml

CLOUD_VOXEL_M = 0.7        # thinning of the prior map for browsers, above the ground
GROUND_VOXEL_M = 1.5       # and on it (the default site: 6.6 M -> about 0.25 M points)
GROUND_BAND_M = 0.25       # points this close above their cell's lowest point are ground
GROUND_CELL_M = 1.0        # ground-height grid for snapping


EMPTY_CLOUD = struct.pack("<I", 0) + struct.pack("<IIfff", 0, 0, 0, 0, GROUND_CELL_M)


class SiteError(Exception):
    pass


def read_pcd(path):
    """x, y, z (float32 arrays) of an ascii or binary PCD file; errors name the file."""
    with open(path, "rb") as f:
        header = {}
        while True:
            line = f.readline()
            if not line:
                raise SiteError(f"{path}: header ends before DATA")
            words = line.decode("ascii", "replace").split()
            if not words or words[0].startswith("#"):
                continue
            header[words[0].upper()] = words[1:]
            if words[0].upper() == "DATA":
                break
        fields, sizes, types = header.get("FIELDS"), header.get("SIZE"), header.get("TYPE")
        counts = header.get("COUNT", ["1"] * len(fields or []))
        n = int(header.get("POINTS", ["0"])[0])
        if not fields or "x" not in fields or not sizes or not types:
            raise SiteError(f"{path}: PCD header without FIELDS x y z / SIZE / TYPE")
        kind = header["DATA"][0]
        dt = np.dtype([(f"{name}_{i}" if int(c) > 1 else name, {"F": "<f", "I": "<i", "U": "<u"}[t] + s)
                       for name, s, t, c in zip(fields, sizes, types, counts) for i in range(int(c))])
        if kind == "binary":
            start = f.tell()
            raw = f.read(n * dt.itemsize)
            if len(raw) < n * dt.itemsize:
                raise SiteError(f"{path}: byte {start + len(raw)}: file ends inside the data "
                                f"({n} points x {dt.itemsize} bytes from byte {start})")
            data = np.frombuffer(raw, dtype=dt, count=n)
        elif kind == "ascii":
            try:
                data = np.loadtxt(f, dtype=dt, max_rows=n, ndmin=1)
            except ValueError as e:
                raise SiteError(f"{path}: ascii data: {e}") from None
        else:
            raise SiteError(f"{path}: PCD DATA {kind} not supported (save it binary or ascii)")
    return data["x"].astype(np.float32), data["y"].astype(np.float32), data["z"].astype(np.float32)


class Site:
    def __init__(self, folder, vehicle_file=None):
        self.dir = pathlib.Path(folder).resolve()
        try:
            site = yaml.safe_load((self.dir / "site.yaml").read_text())
            self.route = yaml.safe_load((self.dir / site.get("route", "route.yaml")).read_text())
        except (OSError, yaml.YAMLError, AttributeError) as e:
            raise SiteError(f"site {folder}: {e}") from None
        self.name = site.get("name", self.dir.name)
        self.map_path = self.dir / ((site.get("map") or {}).get("file", "map.pcd"))
        self.scenarios_dir = self.dir / "scenarios"
        vf = pathlib.Path(vehicle_file or pathlib.Path(__file__).resolve().parents[2] / "vehicles" / "prius2017.yaml")
        try:
            dims = yaml.safe_load(vf.read_text())["dimensions"]
            self.vehicle = {k: float(dims[k]) for k in ("length", "width", "height", "rear_overhang")}
        except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as e:
            raise SiteError(f"vehicle {vf}: {e}") from None
        self._cloud = None
        self._cloud_error = None
        self._lock = threading.Lock()

    def scenario_info(self):
        """Per scenario id: its volumes, synchronised agents' marks, render distance (for the operator)."""
        info = {}
        for p in sorted(self.scenarios_dir.glob("*.yaml")):
            try:
                sc = yaml.safe_load(p.read_text())
                sync = []
                for b in sc.get("behaviours") or []:
                    if b.get("sync"):
                        mark = b["path"][b["sync"]["mark"]]["to"]
                        sync.append({"agent": b["agent"], "stop_line": b["sync"]["stop_line"], "mark": mark})
                info[sc["scenario"]] = {"file": p.stem, "volumes": sc.get("volumes") or [], "sync": sync,
                                        "render_distance_m": sc.get("render_distance_m", 45)}
            except (OSError, yaml.YAMLError, AttributeError, KeyError, IndexError, TypeError):
                continue      # a broken file is the editor's and scenario-check's business, not the display's
        return info

    def summary(self):
        r = self.route
        return {"vehicle": self.vehicle, "scenario_info": self.scenario_info(),"name": self.name, "route": r.get("points", []), "lane_width": r.get("lane_width", 3.5),
                "crosswalks": r.get("crosswalks", []), "stop_lines": r.get("stop_lines", []),
                "scenarios": sorted(p.stem for p in self.scenarios_dir.glob("*.yaml")),
                "has_map": self.map_path.is_file()}

    def cloud_bytes(self):
        """u32 n, n x (f32 x, y, z); then the ground grid: u32 nx, ny, f32 x0, y0, cell, nx*ny f32 (NaN: no data)."""
        with self._lock:
            if self._cloud is None:
                try:
                    self._cloud = self._build_cloud()
                except (SiteError, OSError, ValueError) as e:   # a bad map: pages show none, and say why here
                    self._cloud_error = str(e)
                    print(f"webui: {e}: the pages show no map", file=sys.stderr, flush=True)
                    self._cloud = EMPTY_CLOUD
            return self._cloud

    def cloud_if_ready(self):
        """The cloud bytes if built, else None (never blocks the caller)."""
        if self._lock.acquire(blocking=False):
            try:
                return self._cloud
            finally:
                self._lock.release()
        return None

    def _build_cloud(self):
        if not self.map_path.is_file():
            return EMPTY_CLOUD
        x, y, z = read_pcd(self.map_path)
        ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
        x, y, z = x[ok], y[ok], z[ok]
        # ground: the lowest point of each cell
        x0, y0 = float(x.min()), float(y.min())
        nx = int((x.max() - x0) / GROUND_CELL_M) + 1
        ny = int((y.max() - y0) / GROUND_CELL_M) + 1
        cell = ((y - y0) / GROUND_CELL_M).astype(np.int64) * nx + ((x - x0) / GROUND_CELL_M).astype(np.int64)
        ground = np.full(nx * ny, np.inf, np.float32)
        np.minimum.at(ground, cell, z)
        # one point per voxel (the first): fine above the ground (kerbs, walls, poles), coarse on it,
        # which is most of a road map and says little in a picture
        voxel = np.where(z - ground[cell] < GROUND_BAND_M, GROUND_VOXEL_M, CLOUD_VOXEL_M)
        k = [np.floor((a - a.min()) / voxel).astype(np.int64) for a in (x, y, z)]
        _, first = np.unique(k[0] + (k[1] << 21) + (k[2] << 42) + ((voxel > CLOUD_VOXEL_M).astype(np.int64) << 62),
                             return_index=True)
        pts = np.stack([x[first], y[first], z[first]], 1).astype(np.float32)
        ground[np.isinf(ground)] = np.nan
        return (struct.pack("<I", len(pts)) + pts.tobytes() +
                struct.pack("<IIfff", nx, ny, x0, y0, GROUND_CELL_M) + ground.tobytes())
