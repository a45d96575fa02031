// Measuring a weld run's scale on the review canvas: the reviewer clicks the two ends of a known
// length (a scale bar, the wire's diameter, a gauge in view), types that length in millimetres,
// and the run gets its mm per pixel (PATCH /sequences/{id} with scale_points; the server does
// the arithmetic, so the rule lives in one place). Its timeline then speaks millimetres.

import { api } from "../api.js";
import { mmPerPx } from "../format.js";
import { toast } from "../ui.js";

const $ = (id) => document.getElementById(id);
const HIT = 9; // screen pixels around an end that pick it up

export class ScaleRuler {
  /** @param stage the review Stage (draws `stage.ruler`); @param frame the frame's detail. */
  constructor(stage, frame) {
    this.stage = stage;
    this.frame = frame;
    this.active = false;
    this.points = [];
    this.mmPerPx = null;
    $("measure-scale").addEventListener("click", () => this.toggle());
    $("cancel-scale").addEventListener("click", () => this.active && this.toggle());
    $("save-scale").addEventListener("click", () => this.save());
    $("scale-mm").addEventListener("input", () => this.render());
  }

  /** The run's current scale, shown beside the button (nothing to measure without a run). */
  async load() {
    const button = $("measure-scale");
    if (!this.frame.sequence_id) {
      button.disabled = true;
      button.title = "This frame belongs to no weld run.";
      this.render();
      return;
    }
    try {
      this.mmPerPx = (await api(`/sequences/${this.frame.sequence_id}`)).mm_per_px;
    } catch (error) {
      toast(error.message, "error");
    }
    this.render();
  }

  toggle() {
    this.active = !this.active;
    this.points = [];
    $("measure-scale").setAttribute("aria-pressed", String(this.active));
    $("measure-scale").classList.toggle("active", this.active);
    $("scale-panel").hidden = !this.active;
    this.stage.canvas.classList.toggle("measuring", this.active);
    this.render();
    if (this.active) {
      $("scale-panel").scrollIntoView({ block: "nearest" }); // its length field and Save in view
      this.stage.canvas.focus({ preventScroll: true });
    }
  }

  /** The separation of the two ends in frame pixels (null until both are placed). */
  span() {
    if (this.points.length < 2) return null;
    const [[x0, y0], [x1, y1]] = this.points;
    return Math.hypot(x1 - x0, y1 - y0);
  }

  /** A pointer went down at screen (sx, sy), frame (x, y): pick an end up, or place one. */
  pointerDown(sx, sy, x, y, inside) {
    const hit = this.points.findIndex(([px, py]) => {
      const [qx, qy] = this.stage.toScreen(px, py);
      return Math.hypot(qx - sx, qy - sy) <= HIT;
    });
    if (hit >= 0) return { kind: "ruler", index: hit };
    if (!inside) return null;
    if (this.points.length === 2) this.points = []; // a third click starts again
    this.points.push([x, y]);
    this.render();
    return { kind: "ruler", index: this.points.length - 1 };
  }

  move(index, x, y) {
    this.points[index] = [
      Math.min(this.frame.width, Math.max(0, x)),
      Math.min(this.frame.height, Math.max(0, y)),
    ];
    this.render();
  }

  render() {
    this.stage.ruler = this.active ? this.points : null;
    this.stage.requestRender();
    const span = this.span();
    const mm = Number($("scale-mm").value);
    $("scale-span").textContent = span === null
      ? `${this.points.length} of 2 ends placed`
      : `${span.toFixed(1)} px between the ends` + (mm > 0 ? ` → ${mmPerPx(mm / span)} mm per pixel` : "");
    $("save-scale").disabled = span === null || !(mm > 0);
    $("scale-state").textContent = !this.frame.sequence_id ? ""
      : this.mmPerPx ? `Scale: ${mmPerPx(this.mmPerPx)} mm per pixel.`
        : "No scale yet: the timeline is in pixels.";
  }

  async save() {
    const span = this.span();
    const mm = Number($("scale-mm").value);
    if (span === null || !(mm > 0)) return;
    try {
      const run = await api(`/sequences/${this.frame.sequence_id}`, {
        method: "PATCH",
        json: { scale_points: { points: this.points, distance_mm: mm } },
      });
      this.mmPerPx = run.mm_per_px;
      toast(`The run's scale is now ${mmPerPx(run.mm_per_px)} mm per pixel.`, "ok");
      this.toggle();
    } catch (error) {
      toast(error.message, "error");
    }
  }
}
