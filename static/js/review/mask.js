// A binary mask in frame pixels (one byte per pixel, 0 or 1): PNG codec, brush stamps, and the
// translucent overlay the stage draws over the frame.

export class Mask {
  constructor(width, height, data = new Uint8Array(width * height)) {
    this.width = width;
    this.height = height;
    this.data = data;
  }

  clone() {
    return new Mask(this.width, this.height, this.data.slice());
  }

  /** The centre of the mask's pixels [x, y], or null when it is empty. */
  centroid() {
    let n = 0, sx = 0, sy = 0;
    const { width } = this;
    for (let i = 0; i < this.data.length; i++) {
      if (this.data[i]) { n += 1; sx += i % width; sy += Math.floor(i / width); }
    }
    return n ? [sx / n, sy / n] : null;
  }

  /** The box around the mask's pixels as COCO writes it, [x, y, width, height], or null. */
  bbox() {
    let x0 = Infinity, y0 = Infinity, x1 = -1, y1 = -1;
    for (let i = 0; i < this.data.length; i++) {
      if (!this.data[i]) continue;
      const x = i % this.width, y = (i - x) / this.width;
      if (x < x0) x0 = x;
      if (x > x1) x1 = x;
      if (y < y0) y0 = y;
      y1 = y;
    }
    return x1 < 0 ? null : [x0, y0, x1 - x0 + 1, y1 - y0 + 1];
  }

  any() {
    return this.data.some((v) => v !== 0);
  }

  area() {
    let n = 0;
    for (const v of this.data) n += v;
    return n;
  }

  equals(other) {
    if (!other || other.width !== this.width || other.height !== this.height) return false;
    if (other === this) return true;
    const a = this.data;
    const b = other.data;
    for (let i = 0; i < a.length; i++) if (a[i] !== b[i]) return false;
    return true;
  }

  /** A mask from a base64 PNG (0 / 255; any channel count); resized by nearest neighbour if needed. */
  static async fromPng(base64, width, height) {
    const bytes = Uint8Array.from(atob(base64), (c) => c.charCodeAt(0));
    const bitmap = await createImageBitmap(new Blob([bytes], { type: "image/png" }), {
      premultiplyAlpha: "none", colorSpaceConversion: "none",
    });
    const canvas = new OffscreenCanvas(width, height);
    const ctx = canvas.getContext("2d", { willReadFrequently: true });
    ctx.imageSmoothingEnabled = false;
    ctx.drawImage(bitmap, 0, 0, width, height);
    bitmap.close();
    const rgba = ctx.getImageData(0, 0, width, height).data;
    const data = new Uint8Array(width * height);
    for (let i = 0, j = 0; i < data.length; i++, j += 4) data[i] = rgba[j] >= 128 ? 1 : 0;
    return new Mask(width, height, data);
  }

  /** A mask from COCO's compressed RLE (`counts` a string, runs down the columns, 0s first):
   *  how the server stores the other classes' regions. */
  static fromRle(counts, width, height) {
    const data = new Uint8Array(width * height);
    let at = 0;
    let previous = [0, 0];
    let value = 0;
    for (let p = 0, m = 0; p < counts.length; m++) {
      let x = 0, k = 0, more = true, c = 0;
      while (more) {
        c = counts.charCodeAt(p++) - 48;
        x += (c & 0x1f) * 2 ** (5 * k);
        more = (c & 0x20) !== 0;
        k++;
      }
      if (c & 0x10) x -= 2 ** (5 * k); // the last group's sign bit
      if (m > 2) x += previous[0]; // runs after the third are stored as the change from two back
      previous = [previous[1], x];
      if (value) for (let i = at; i < at + x; i++) data[(i % height) * width + Math.floor(i / height)] = 1;
      at += x;
      value = 1 - value;
    }
    return new Mask(width, height, data);
  }

  /** The mask as a base64 PNG with values 0 / 255. */
  async toPng() {
    const canvas = new OffscreenCanvas(this.width, this.height);
    const ctx = canvas.getContext("2d");
    const image = ctx.createImageData(this.width, this.height);
    const rgba = image.data;
    for (let i = 0, j = 0; i < this.data.length; i++, j += 4) {
      const v = this.data[i] ? 255 : 0;
      rgba[j] = v; rgba[j + 1] = v; rgba[j + 2] = v; rgba[j + 3] = 255;
    }
    ctx.putImageData(image, 0, 0);
    const blob = await canvas.convertToBlob({ type: "image/png" });
    const bytes = new Uint8Array(await blob.arrayBuffer());
    let text = "";
    for (let i = 0; i < bytes.length; i += 0x8000) text += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
    return btoa(text);
  }

  /** Paint a disc of `radius` at (cx, cy) with `value`; returns the touched rectangle. */
  stamp(cx, cy, radius, value) {
    const x0 = Math.max(0, Math.floor(cx - radius));
    const x1 = Math.min(this.width - 1, Math.ceil(cx + radius));
    const y0 = Math.max(0, Math.floor(cy - radius));
    const y1 = Math.min(this.height - 1, Math.ceil(cy + radius));
    const r2 = radius * radius;
    for (let y = y0; y <= y1; y++) {
      const dy = y - cy;
      const row = y * this.width;
      for (let x = x0; x <= x1; x++) {
        const dx = x - cx;
        if (dx * dx + dy * dy <= r2) this.data[row + x] = value;
      }
    }
    return { x0, y0, x1, y1 };
  }

  /** A brush stroke segment from (ax, ay) to (bx, by); returns the touched rectangle. */
  line(ax, ay, bx, by, radius, value) {
    const steps = Math.max(1, Math.ceil(Math.hypot(bx - ax, by - ay) / Math.max(0.5, radius / 3)));
    let rect = null;
    for (let s = 0; s <= steps; s++) {
      const t = s / steps;
      rect = union(rect, this.stamp(ax + (bx - ax) * t, ay + (by - ay) * t, radius, value));
    }
    return rect;
  }
}

export function union(a, b) {
  if (!a) return b;
  if (!b) return a;
  return { x0: Math.min(a.x0, b.x0), y0: Math.min(a.y0, b.y0), x1: Math.max(a.x1, b.x1), y1: Math.max(a.y1, b.y1) };
}

const FILL = [0, 184, 255, 96];
const EDGE = [0, 230, 255, 255];

/** "#rrggbb" as [r, g, b]. */
export const rgb = (hex) => [1, 3, 5].map((i) => parseInt(hex.slice(i, i + 2), 16));

/** Draw the frame pixels x0..x1 × y0..y1 of `mask` into `out` (RGBA of a canvas whose top-left
 *  is frame pixel (ox, oy), `span` pixels wide): the fill inside (or nothing, `filled` off), the
 *  edge opaque, nothing outside the mask. */
function drawMask(mask, out, ox, oy, span, { x0, y0, x1, y1 }, fill, edge, filled) {
  const { width, height } = mask;
  const m = mask.data;
  for (let y = y0; y <= y1; y++) {
    for (let x = x0; x <= x1; x++) {
      const i = y * width + x;
      const j = ((y - oy) * span + (x - ox)) * 4;
      if (!m[i]) { out[j + 3] = 0; continue; }
      const isEdge = x === 0 || y === 0 || x === width - 1 || y === height - 1
        || !m[i - 1] || !m[i + 1] || !m[i - width] || !m[i + width];
      if (!isEdge && !filled) { out[j + 3] = 0; continue; }
      const c = isEdge ? edge : fill;
      out[j] = c[0]; out[j + 1] = c[1]; out[j + 2] = c[2]; out[j + 3] = c[3];
    }
  }
}

/** `rect` one pixel wider on each side (a stroke changes its neighbours' edges), inside the frame. */
const widened = (rect, width, height) => ({
  x0: Math.max(0, rect.x0 - 1), y0: Math.max(0, rect.y0 - 1), x1: Math.min(width - 1, rect.x1 + 1), y1: Math.min(height - 1, rect.y1 + 1),
});

/** The mask drawn as a translucent fill (or none: outline only) with an opaque outline, on a
 * canvas of the frame's size: the pool's overlay. */
export class MaskOverlay {
  /** `colour` ("#rrggbb"): another class's overlay; none: the pool's. */
  constructor(width, height, colour = null) {
    this.fill = colour ? [...rgb(colour), 110] : FILL;
    this.edge = colour ? [...rgb(colour), 255] : EDGE;
    this.canvas = new OffscreenCanvas(width, height);
    this.ctx = this.canvas.getContext("2d");
    this.image = this.ctx.createImageData(width, height);
    this.mask = null;
    this.filled = true;
    this.x = 0;
    this.y = 0;
  }

  /** Fill the inside, or draw the outline only (what lies under the mask stays readable). */
  setFilled(on) {
    if (on === this.filled) return;
    this.filled = on;
    if (this.mask) this.paint(this.mask);
  }

  /** Redraw everything (a new mask) or only `rect` (a brush stroke on the same mask). */
  paint(mask, rect = null) {
    const { width, height } = mask;
    const full = rect === null || mask !== this.mask;
    this.mask = mask;
    const area = full ? { x0: 0, y0: 0, x1: width - 1, y1: height - 1 } : widened(rect, width, height);
    drawMask(mask, this.image.data, 0, 0, width, area, this.fill, this.edge, this.filled);
    this.ctx.putImageData(this.image, 0, 0, area.x0, area.y0, area.x1 - area.x0 + 1, area.y1 - area.y0 + 1);
  }

  /** Bytes of pixels this overlay holds (its canvas and its image data). */
  get bytes() {
    return this.canvas.width * this.canvas.height * 8;
  }
}

/** How far a box grows past a stroke that leaves it: a stroke outward does not regrow it at
 *  every step. */
const GROWTH = 32;

/** An object's overlay, as MaskOverlay draws it, on a canvas only as big as the box of its
 *  mask (none when empty), at frame pixel (x, y); grown when a stroke paints beyond it. Memory
 *  follows the object's size, not the frame's. */
export class ObjectOverlay {
  constructor(colour) {
    this.fill = [...rgb(colour), 110];
    this.edge = [...rgb(colour), 255];
    this.canvas = null;
    this.image = null;
    this.box = null; // {x0, y0, x1, y1} in frame pixels: what the canvas covers
    this.mask = null;
    this.x = 0;
    this.y = 0;
  }

  /** Redraw everything (a new mask: the canvas fits its box again) or only `rect` (a stroke on
   *  the same mask: the canvas grows first when the stroke leaves it). */
  paint(mask, rect = null) {
    const { width, height } = mask;
    const full = rect === null || mask !== this.mask;
    this.mask = mask;
    if (full) {
      const bbox = mask.bbox();
      this.cover(bbox && widened({ x0: bbox[0], y0: bbox[1], x1: bbox[0] + bbox[2] - 1, y1: bbox[1] + bbox[3] - 1 }, width, height));
      return;
    }
    const area = widened(rect, width, height);
    const box = this.box;
    if (!box || area.x0 < box.x0 || area.y0 < box.y0 || area.x1 > box.x1 || area.y1 > box.y1) {
      const grown = union(box, widened({ x0: area.x0 - GROWTH, y0: area.y0 - GROWTH, x1: area.x1 + GROWTH, y1: area.y1 + GROWTH }, width, height));
      this.cover(grown);
      return;
    }
    this.draw(area);
  }

  /** A canvas for `box` (null: none), drawn whole from the mask. */
  cover(box) {
    this.box = box;
    if (!box) { this.canvas = this.image = null; return; }
    this.x = box.x0;
    this.y = box.y0;
    this.canvas = new OffscreenCanvas(box.x1 - box.x0 + 1, box.y1 - box.y0 + 1);
    this.ctx = this.canvas.getContext("2d");
    this.image = this.ctx.createImageData(this.canvas.width, this.canvas.height);
    this.draw(box);
  }

  draw(area) {
    drawMask(this.mask, this.image.data, this.x, this.y, this.canvas.width, area, this.fill, this.edge, true);
    this.ctx.putImageData(this.image, 0, 0, area.x0 - this.x, area.y0 - this.y, area.x1 - area.x0 + 1, area.y1 - area.y0 + 1);
  }

  /** Bytes of pixels this overlay holds (its canvas and its image data). */
  get bytes() {
    return this.canvas ? this.canvas.width * this.canvas.height * 8 : 0;
  }
}
