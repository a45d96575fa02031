// The review canvas: the frame under a zoom / pan transform, the other classes' layers, the
// mask and heatmap overlays, click prompts, the box being drawn, numbered keypoints, the scale ruler and the brush cursor.

const KEYPOINT_RADIUS = 9;
const COLOURS = {
  keypoint: "#ffb000",
  manual: "#ff3d9a",
  positive: "#2fb344",
  negative: "#e03131",
  box: "#00b8ff",
  outline: "#00e6ff",
  hole: "#ffd43b",
  ruler: "#f8f9fa",
};
const VERTEX_HIT = 7; // screen pixels around a vertex or an edge that pick it
const HANDLES_FROM = 16; // screen pixels: smaller polygons (specks) are drawn without handles

export class Stage {
  constructor(canvas, width, height) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.width = width;
    this.height = height;
    this.scale = 1;
    this.tx = 0;
    this.ty = 0;
    this.fitted = true;
    this.image = null;
    this.overlay = null;
    this.heatmap = null;
    this.showMask = true;
    this.showHeatmap = false;
    this.keypoints = [];
    /** The other classes' masks under the pool's: [{overlay, alpha}], each overlay as big as its object
     *  (mask.js ObjectOverlay, drawn at its x, y); their named points:
     *  [{x, y, name, colour, selected}]. */
    this.layers = [];
    this.namedPoints = [];
    this.keypointStyle = "keypoint";
    this.dimKeypoints = false;
    /** How the frame is shown (never what is saved): brightness, contrast, gamma, overlays. */
    this.display = { brightness: 1, contrast: 1, gamma: 1, maskOpacity: 1, keypoints: true };
    this.selected = -1;
    this.points = [];
    this.box = null;
    this.draft = null;
    /** The outline being edited (polygon tool): [{points: [[x, y]…], hole}], or null. */
    this.polygons = null;
    this.selectedVertex = null; // {polygon, index}
    /** A new polygon being drawn corner by corner (polygon tool): {layer, points}, or null. */
    this.newPolygon = null;
    /** The scale being measured: [[x, y]] or [[x, y], [x, y]] in frame pixels, or null. */
    this.ruler = null;
    this.cursor = null;
    this.pending = false;
    this.onViewChange = () => {};
    new ResizeObserver(() => this.resize()).observe(canvas.parentElement);
    this.resize();
  }

  resize() {
    const box = this.canvas.parentElement.getBoundingClientRect();
    const dpr = window.devicePixelRatio || 1;
    this.cssWidth = Math.max(1, box.width);
    this.cssHeight = Math.max(1, box.height);
    this.canvas.width = Math.round(this.cssWidth * dpr);
    this.canvas.height = Math.round(this.cssHeight * dpr);
    this.canvas.style.width = `${this.cssWidth}px`;
    this.canvas.style.height = `${this.cssHeight}px`;
    if (this.fitted) this.fit();
    this.render();
  }

  // --- the view transform -------------------------------------------------------------------

  fit() {
    const margin = 16;
    this.scale = Math.min((this.cssWidth - margin) / this.width, (this.cssHeight - margin) / this.height);
    this.tx = (this.cssWidth - this.width * this.scale) / 2;
    this.ty = (this.cssHeight - this.height * this.scale) / 2;
    this.fitted = true;
    this.onViewChange();
    this.requestRender();
  }

  /** Zoom by `factor` keeping the frame point under the screen point (sx, sy) in place. */
  zoomAt(factor, sx, sy) {
    const fitScale = Math.min(this.cssWidth / this.width, this.cssHeight / this.height);
    const scale = Math.min(40, Math.max(fitScale * 0.25, this.scale * factor));
    const [ix, iy] = this.toImage(sx, sy);
    this.scale = scale;
    this.tx = sx - ix * scale;
    this.ty = sy - iy * scale;
    this.fitted = false;
    this.onViewChange();
    this.requestRender();
  }

  panBy(dx, dy) {
    this.tx += dx;
    this.ty += dy;
    this.fitted = false;
    this.onViewChange();
    this.requestRender();
  }

  /** Screen (CSS pixels, relative to the canvas) to frame pixels. */
  toImage(sx, sy) {
    return [(sx - this.tx) / this.scale, (sy - this.ty) / this.scale];
  }

  toScreen(x, y) {
    return [x * this.scale + this.tx, y * this.scale + this.ty];
  }

  /** The index of the keypoint under the screen point, or -1. */
  keypointAt(sx, sy) {
    for (let i = this.keypoints.length - 1; i >= 0; i--) {
      const [px, py] = this.toScreen(...this.keypoints[i]);
      if (Math.hypot(px - sx, py - sy) <= KEYPOINT_RADIUS + 3) return i;
    }
    return -1;
  }

  /** Whether a polygon is big enough on screen to show (and pick) its vertices. */
  editable(polygon) {
    const xs = polygon.points.map((q) => q[0]);
    const ys = polygon.points.map((q) => q[1]);
    const extent = Math.max(Math.max(...xs) - Math.min(...xs), Math.max(...ys) - Math.min(...ys));
    return extent * this.scale >= HANDLES_FROM;
  }

  /** Whether the screen point is on the first corner of the new polygon (a click there closes it). */
  onFirstCorner(sx, sy) {
    const points = this.newPolygon?.points ?? [];
    if (points.length < 3) return false;
    const [px, py] = this.toScreen(...points[0]);
    return Math.hypot(px - sx, py - sy) <= VERTEX_HIT;
  }

  /** The outline vertex under the screen point, {polygon, index}, or null. */
  vertexAt(sx, sy) {
    if (!this.polygons) return null;
    let best = null;
    this.polygons.forEach((polygon, p) => this.editable(polygon) && polygon.points.forEach(([x, y], i) => {
      const [px, py] = this.toScreen(x, y);
      const d = Math.hypot(px - sx, py - sy);
      if (d <= VERTEX_HIT && (!best || d < best.d)) best = { polygon: p, index: i, d };
    }));
    return best && { polygon: best.polygon, index: best.index };
  }

  /** The outline edge under the screen point: {polygon, index (insert before), x, y}, or null. */
  edgeAt(sx, sy) {
    if (!this.polygons) return null;
    let best = null;
    this.polygons.forEach((polygon, p) => this.editable(polygon) && polygon.points.forEach((a, i) => {
      const b = polygon.points[(i + 1) % polygon.points.length];
      const [ax, ay] = this.toScreen(...a);
      const [bx, by] = this.toScreen(...b);
      const length2 = (bx - ax) ** 2 + (by - ay) ** 2 || 1;
      const t = Math.min(1, Math.max(0, ((sx - ax) * (bx - ax) + (sy - ay) * (by - ay)) / length2));
      const d = Math.hypot(ax + t * (bx - ax) - sx, ay + t * (by - ay) - sy);
      if (d <= VERTEX_HIT && (!best || d < best.d)) {
        best = { polygon: p, index: i + 1, x: a[0] + t * (b[0] - a[0]), y: a[1] + t * (b[1] - a[1]), d };
      }
    }));
    return best && { polygon: best.polygon, index: best.index, x: best.x, y: best.y };
  }

  // --- drawing ------------------------------------------------------------------------------

  requestRender() {
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => { this.pending = false; this.render(); });
  }

  render() {
    const { ctx } = this;
    const dpr = window.devicePixelRatio || 1;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#11151a";
    ctx.fillRect(0, 0, this.canvas.width, this.canvas.height);
    ctx.setTransform(dpr * this.scale, 0, 0, dpr * this.scale, dpr * this.tx, dpr * this.ty);
    ctx.imageSmoothingEnabled = this.scale < 2;
    if (this.image) {
      const { brightness, contrast, gamma } = this.display;
      const filters = [];
      if (brightness !== 1) filters.push(`brightness(${brightness})`);
      if (contrast !== 1) filters.push(`contrast(${contrast})`);
      if (gamma !== 1) filters.push("url(#gamma-filter)"); // exponent 1/gamma, set by the page
      ctx.filter = filters.join(" ") || "none";
      ctx.drawImage(this.image, 0, 0, this.width, this.height);
      ctx.filter = "none";
    }
    if (this.showHeatmap && this.heatmap) {
      ctx.globalAlpha = 0.7;
      ctx.drawImage(this.heatmap, 0, 0, this.width, this.height);
      ctx.globalAlpha = 1;
    }
    for (const { overlay, alpha } of this.layers) { // each as big as its object (mask.js)
      if (!overlay.canvas) continue;
      ctx.globalAlpha = alpha;
      ctx.drawImage(overlay.canvas, overlay.x, overlay.y);
    }
    ctx.globalAlpha = 1;
    if (this.showMask && this.overlay && this.display.maskOpacity > 0) {
      ctx.globalAlpha = this.display.maskOpacity;
      ctx.drawImage(this.overlay.canvas, 0, 0);
      ctx.globalAlpha = 1;
    }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    this.drawBox(this.box, false);
    this.drawBox(this.draft, true);
    this.points.forEach((p) => this.drawPrompt(p));
    this.drawPolygons();
    this.drawNewPolygon();
    if (this.display.keypoints) this.drawKeypoints();
    this.drawNamedPoints();
    this.drawRuler();
    this.drawCursor();
  }

  drawBox(box, draft) {
    if (!box) return;
    const { ctx } = this;
    const [x0, y0] = this.toScreen(box[0], box[1]);
    const [x1, y1] = this.toScreen(box[2], box[3]);
    ctx.save();
    ctx.strokeStyle = COLOURS.box;
    ctx.lineWidth = 2;
    if (draft) ctx.setLineDash([6, 4]);
    ctx.strokeRect(x0, y0, x1 - x0, y1 - y0);
    ctx.restore();
  }

  drawPolygons() {
    if (!this.polygons) return;
    const { ctx } = this;
    ctx.save();
    for (const [p, polygon] of this.polygons.entries()) {
      const colour = polygon.hole ? COLOURS.hole : COLOURS.outline;
      ctx.beginPath();
      polygon.points.forEach(([x, y], i) => {
        const [px, py] = this.toScreen(x, y);
        if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
      });
      ctx.closePath();
      ctx.lineWidth = 1.5;
      ctx.strokeStyle = colour;
      ctx.stroke();
      if (!this.editable(polygon)) continue;
      polygon.points.forEach(([x, y], i) => {
        const [px, py] = this.toScreen(x, y);
        const selected = this.selectedVertex?.polygon === p && this.selectedVertex.index === i;
        const r = selected ? 5 : 3.5;
        ctx.fillStyle = selected ? "#fff" : colour;
        ctx.fillRect(px - r, py - r, 2 * r, 2 * r);
        ctx.lineWidth = 1;
        ctx.strokeStyle = "#11151a";
        ctx.strokeRect(px - r, py - r, 2 * r, 2 * r);
      });
    }
    ctx.restore();
  }

  /** The new polygon's corners joined by a dashed line, not yet closed. */
  drawNewPolygon() {
    const points = this.newPolygon?.points;
    if (!points?.length) return;
    const { ctx } = this;
    ctx.save();
    ctx.beginPath();
    points.forEach(([x, y], i) => {
      const [px, py] = this.toScreen(x, y);
      if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
    });
    ctx.lineWidth = 4; // a dark halo under the dashes: seen over any overlay of the same colour
    ctx.strokeStyle = "rgba(0, 0, 0, 0.75)";
    ctx.stroke();
    ctx.setLineDash([6, 4]);
    ctx.lineWidth = 1.5;
    ctx.strokeStyle = COLOURS.outline;
    ctx.stroke();
    ctx.setLineDash([]);
    points.forEach(([x, y], i) => {
      const [px, py] = this.toScreen(x, y);
      const r = i === 0 ? 5 : 3.5; // the first corner, larger: click it to close
      ctx.fillStyle = "rgba(0, 0, 0, 0.75)";
      ctx.fillRect(px - r - 1.5, py - r - 1.5, 2 * r + 3, 2 * r + 3);
      ctx.fillStyle = COLOURS.outline;
      ctx.fillRect(px - r, py - r, 2 * r, 2 * r);
    });
    ctx.restore();
  }

  drawPrompt(point) {
    const { ctx } = this;
    const [x, y] = this.toScreen(point.x, point.y);
    ctx.beginPath();
    ctx.arc(x, y, 7, 0, Math.PI * 2);
    ctx.fillStyle = point.positive ? COLOURS.positive : COLOURS.negative;
    ctx.fill();
    ctx.lineWidth = 2;
    ctx.strokeStyle = "#fff";
    ctx.stroke();
    ctx.beginPath();
    ctx.moveTo(x - 3.5, y);
    ctx.lineTo(x + 3.5, y);
    if (point.positive) { ctx.moveTo(x, y - 3.5); ctx.lineTo(x, y + 3.5); }
    ctx.stroke();
  }

  drawKeypoints() {
    const { ctx } = this;
    const colour = COLOURS[this.keypointStyle];
    ctx.save();
    ctx.globalAlpha = this.dimKeypoints ? 0.45 : 1;
    ctx.font = "bold 11px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.textBaseline = "middle";
    this.keypoints.forEach(([kx, ky], i) => {
      const [x, y] = this.toScreen(kx, ky);
      ctx.beginPath();
      if (this.keypointStyle === "manual") {
        ctx.moveTo(x, y - KEYPOINT_RADIUS - 1);
        ctx.lineTo(x + KEYPOINT_RADIUS + 1, y);
        ctx.lineTo(x, y + KEYPOINT_RADIUS + 1);
        ctx.lineTo(x - KEYPOINT_RADIUS - 1, y);
        ctx.closePath();
      } else {
        ctx.arc(x, y, KEYPOINT_RADIUS, 0, Math.PI * 2);
      }
      ctx.fillStyle = colour;
      ctx.fill();
      ctx.lineWidth = i === this.selected ? 3 : 1.5;
      ctx.strokeStyle = i === this.selected ? "#fff" : "#1d232b";
      ctx.stroke();
      ctx.fillStyle = "#1d232b";
      ctx.fillText(String(this.keypointNumbers?.[i] ?? i + 1), x, y + 0.5);
    });
    ctx.restore();
  }

  /** The points classes' named points: a square in the class's colour with its name. */
  drawNamedPoints() {
    const { ctx } = this;
    ctx.save();
    ctx.font = "bold 11px system-ui, sans-serif";
    ctx.textBaseline = "middle";
    for (const point of this.namedPoints) {
      const [x, y] = this.toScreen(point.x, point.y);
      const r = point.selected ? 7 : 5.5;
      ctx.globalAlpha = point.alpha ?? 1;
      ctx.fillStyle = point.colour;
      ctx.fillRect(x - r, y - r, 2 * r, 2 * r);
      ctx.lineWidth = point.selected ? 2.5 : 1.5;
      ctx.strokeStyle = point.selected ? "#fff" : "#1d232b";
      ctx.strokeRect(x - r, y - r, 2 * r, 2 * r);
      ctx.lineWidth = 3;
      ctx.strokeStyle = "#1d232b";
      ctx.strokeText(point.name, x + r + 4, y);
      ctx.fillText(point.name, x + r + 4, y);
    }
    ctx.restore();
  }

  /** The scale's two ends as crosshairs joined by a line labelled with its length in pixels. */
  drawRuler() {
    if (!this.ruler?.length) return;
    const { ctx } = this;
    const ends = this.ruler.map(([x, y]) => this.toScreen(x, y));
    ctx.save();
    ctx.strokeStyle = COLOURS.ruler;
    ctx.shadowColor = "#000";
    ctx.shadowBlur = 3;
    ctx.lineWidth = 1.5;
    if (ends.length === 2) {
      ctx.beginPath();
      ctx.moveTo(...ends[0]);
      ctx.lineTo(...ends[1]);
      ctx.stroke();
    }
    for (const [x, y] of ends) {
      ctx.beginPath();
      ctx.moveTo(x - 8, y); ctx.lineTo(x + 8, y);
      ctx.moveTo(x, y - 8); ctx.lineTo(x, y + 8);
      ctx.stroke();
      ctx.beginPath();
      ctx.arc(x, y, 4, 0, Math.PI * 2);
      ctx.stroke();
    }
    if (ends.length === 2) {
      const [[x0, y0], [x1, y1]] = this.ruler;
      ctx.font = "bold 12px system-ui, sans-serif";
      ctx.fillStyle = COLOURS.ruler;
      ctx.textAlign = "center";
      ctx.fillText(`${Math.hypot(x1 - x0, y1 - y0).toFixed(1)} px`, (ends[0][0] + ends[1][0]) / 2, (ends[0][1] + ends[1][1]) / 2 - 10);
    }
    ctx.restore();
  }

  drawCursor() {
    if (!this.cursor) return;
    const { ctx } = this;
    const [x, y] = this.toScreen(this.cursor.x, this.cursor.y);
    ctx.save();
    ctx.beginPath();
    ctx.arc(x, y, Math.max(1, this.cursor.radius * this.scale), 0, Math.PI * 2);
    ctx.lineWidth = 1.5;
    ctx.strokeStyle = this.cursor.erase ? COLOURS.negative : "#fff";
    ctx.setLineDash([4, 3]);
    ctx.stroke();
    ctx.restore();
  }
}
