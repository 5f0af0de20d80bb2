// Top-down drawing of the site on a 2-D canvas (the operator's 7-inch screen): route,
// crosswalks, stop lines and trigger volumes, in map metres with y up.
const CLOUD_PX_PER_M = 4;

export class TopDown {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.cx = 0; this.cy = 0; this.scale = 6;   // px per metre
  }
  resize() {
    const r = this.canvas.getBoundingClientRect();
    this.canvas.width = r.width * devicePixelRatio;
    this.canvas.height = r.height * devicePixelRatio;
  }
  px(x, y) {   // map -> canvas pixels
    return [this.canvas.width / 2 + (x - this.cx) * this.scale, this.canvas.height / 2 - (y - this.cy) * this.scale];
  }
  begin() {
    const c = this.ctx;
    c.setTransform(1, 0, 0, 1, 0, 0);
    c.fillStyle = "#1b1d20";
    c.fillRect(0, 0, this.canvas.width, this.canvas.height);
  }
  poly(pts, close, stroke, fill, width = 1) {
    const c = this.ctx;
    c.beginPath();
    pts.forEach(([x, y], i) => { const [u, v] = this.px(x, y); i ? c.lineTo(u, v) : c.moveTo(u, v); });
    if (close) c.closePath();
    if (fill) { c.fillStyle = fill; c.fill(); }
    if (stroke) { c.strokeStyle = stroke; c.lineWidth = width * devicePixelRatio; c.stroke(); }
  }
  rect(cx, cy, yaw, len, wid) {   // corners of an oriented rectangle (len along yaw)
    const c = Math.cos(yaw), s = Math.sin(yaw);
    return [[len / 2, wid / 2], [-len / 2, wid / 2], [-len / 2, -wid / 2], [len / 2, -wid / 2]]
      .map(([a, b]) => [cx + a * c - b * s, cy + a * s + b * c]);
  }
  // The prior map from above, drawn once into an image at CLOUD_PX_PER_M (what stands above
  // the ground: the ground adds nothing from above) and then only copied each frame.
  cloud(points) {
    if (points !== this.cloudSrc) {
      this.cloudSrc = points;
      let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
      for (let i = 0; i < points.length; i += 3) {
        x0 = Math.min(x0, points[i]); x1 = Math.max(x1, points[i]); y0 = Math.min(y0, points[i + 1]); y1 = Math.max(y1, points[i + 1]);
      }
      const k = CLOUD_PX_PER_M, img = document.createElement("canvas");
      img.width = Math.max(1, Math.ceil((x1 - x0) * k)); img.height = Math.max(1, Math.ceil((y1 - y0) * k));
      const c = img.getContext("2d");
      for (let i = 0; i < points.length; i += 3) {
        const z = points[i + 2];
        if (z < 0.3) continue;
        c.fillStyle = z > 3 ? "#4a5568" : "#6b7280";
        c.fillRect((points[i] - x0) * k, (y1 - points[i + 1]) * k, 1.5, 1.5);
      }
      this.cloudImg = { img, x0, y1 };
    }
    if (!this.cloudImg) return;
    const { img, x0, y1 } = this.cloudImg;
    const [u, v] = this.px(x0, y1);
    this.ctx.drawImage(img, u, v, img.width * this.scale / CLOUD_PX_PER_M, img.height * this.scale / CLOUD_PX_PER_M);
  }
  site(site) {
    const lw = site.lane_width;
    this.poly(site.route, true, "#3a3f47", null, lw * this.scale / devicePixelRatio * 2);
    this.poly(site.route, true, "#8892a0", null, 1);
    for (const cw of site.crosswalks) {
      this.poly(this.rect(cw.center[0], cw.center[1], (cw.yaw_deg + 90) * Math.PI / 180, cw.length, cw.width), true,
        "#d0d0d0", "rgba(220,220,220,0.25)", 1);
    }
    for (const sl of site.stop_lines) {
      const y = sl.yaw_deg * Math.PI / 180, n = [-Math.sin(y), Math.cos(y)];
      this.poly([[sl.xy[0] - n[0] * lw / 2, sl.xy[1] - n[1] * lw / 2], [sl.xy[0] + n[0] * lw / 2, sl.xy[1] + n[1] * lw / 2]],
        false, "#f5f5f5", null, 3);
    }
  }
  volume(v, stroke = "#4fa3ff", fill = "rgba(79,163,255,0.12)") {
    if (v.type === "box") this.poly(this.rect(v.center[0], v.center[1], (v.yaw_deg || 0) * Math.PI / 180, v.size[0], v.size[1]), true, stroke, fill, 1.5);
    else if (v.type === "prism") this.poly(v.points, true, stroke, fill, 1.5);
    else if (v.type === "cylinder") {
      const c = this.ctx, [u, w] = this.px(v.center[0], v.center[1]);
      c.beginPath(); c.arc(u, w, v.radius * this.scale, 0, 2 * Math.PI);
      c.fillStyle = fill; c.fill(); c.strokeStyle = stroke; c.lineWidth = 1.5 * devicePixelRatio; c.stroke();
    }
  }
  label(x, y, text, color = "#eee", size = 12, dx = 8, dy = -8) {
    const [u, v] = this.px(x, y);
    const c = this.ctx;
    c.font = `${size * devicePixelRatio}px sans-serif`;
    c.fillStyle = color;
    c.fillText(text, u + dx * devicePixelRatio, v + dy * devicePixelRatio);
  }
}

export const KIND_COLOUR = { pedestrian: "#ffb020", cyclist: "#33d6c4", vehicle: "#c084fc", object: "#a3a3a3" };
