// The one place that turns numbers into text on every page: same units, same rounding.

import { badge, h } from "./ui.js";

/** mIoU and other fractions of overlap: three decimals ("0.874"). */
export const iou = (v) => (typeof v === "number" ? v.toFixed(3) : "–");
/** Distances in pixels: one decimal ("11.4 px"). */
export const px = (v) => (typeof v === "number" ? `${v.toFixed(1)} px` : "–");
/** Scores between 0 and 1 a model gives itself (uncertainty, confidence, SAM2's predicted IoU):
 * two decimals ("0.42"). */
export const score = (v) => (typeof v === "number" ? v.toFixed(2) : "–");
/** A scale in millimetres per pixel: three significant digits, no trailing zeros ("0.05"). */
export const mmPerPx = (v) => (typeof v === "number" ? String(Number(v.toPrecision(3))) : "–");
/** Rates: a whole percent below 10 % shows one decimal ("87 %", "4.5 %"). */
export const pct = (v) => (typeof v === "number" ? `${(100 * v).toFixed(100 * v < 10 ? 1 : 0)} %` : "–");
/** One class's agreement between annotators (`/frames/{id}/overlap` `classes`): "IoU 0.333",
 *  "IoU 0.250 · 1.0 objects apart", "tip 5.0 px · root 0.0 px". */
export function classAgreement(c) {
  if (c.kind === "points") {
    const named = Object.entries(c.points_px ?? {});
    return named.length ? named.map(([name, v]) => `${name} ${px(v)}`).join(" · ") : "no point both placed";
  }
  const apart = typeof c.count_diff === "number" ? ` · ${c.count_diff % 1 ? c.count_diff.toFixed(1) : c.count_diff} ${c.count_diff === 1 ? "object" : "objects"} apart` : "";
  return `IoU ${iou(c.iou)}${apart}`;
}
/** "1 job", "3 jobs", "1 frame". */
export const count = (n, word, plural = `${word}s`) => `${n} ${n === 1 ? word : plural}`;
/** A duration given in seconds: "45 s", "9.5 min", "2.1 h". */
export function duration(seconds) {
  if (typeof seconds !== "number") return "–";
  if (seconds < 90) return `${Math.round(seconds)} s`;
  if (seconds < 5400) return `${(seconds / 60).toFixed(1)} min`;
  return `${(seconds / 3600).toFixed(1)} h`;
}
/** "every frame", "every 2nd frame", "every 25th frame". */
export function everyNth(n) {
  if (n <= 1) return "every frame";
  const tens = n % 100;
  const suffix = tens >= 11 && tens <= 13 ? "th" : { 1: "st", 2: "nd", 3: "rd" }[n % 10] ?? "th";
  return `every ${n}${suffix} frame`;
}

const COUNTS = /^(frames|validation_frames|pseudo_labels|best_epoch|missed|epochs|steps|labels)$/;

/** What a stored metric's key means, in the words the pages show (the key stays in the tooltip). */
const METRIC_NAMES = {
  mIoU: "mIoU (mask overlap)",
  mED: "mED (mean keypoint distance)",
  mED_k: "mED per keypoint (1, 2, …)",
  mED_penalised: "mED, a missed keypoint counted as far off",
  std: "spread of keypoint distances (std)",
  missed: "keypoints missed",
  frames: "frames measured",
  validation_frames: "held-out frames",
  best_epoch: "best epoch (the one kept)",
  pseudo_labels: "teacher pseudo-labels",
  epochs: "epochs",
  med: "mED",
  med_k: "mED per keypoint",
  mask_loss: "mask loss",
  heatmap_loss: "heatmap loss",
  kl: "KL divergence",
  beta: "β (KL weight)",
  learning_rate: "learning rate",
  seconds: "seconds per round",
  step: "steps",
  score: "selection score",
  pretrained: "pretrained encoder",
};

/** A metric's key as words: the known ones by name, any other with its underscores as spaces. */
export const metricName = (key) => METRIC_NAMES[key] ?? key.replaceAll("_", " ");

/** A metric of a student version or a run, by its name: mIoU, distances, counts, flags. */
export function metric(name, value) {
  if (Array.isArray(value)) return value.map((v) => metric(name, v)).join(" · ");
  if (typeof value === "boolean") return value ? "yes" : "no";
  if (typeof value !== "number") return value === null || value === undefined ? "–" : String(value);
  if (COUNTS.test(name)) return String(Math.round(value));
  if (/iou|acc|f1|dice/i.test(name)) return iou(value);
  if (/^m?ed|_k$|std|px/i.test(name)) return px(value);
  return String(Number(value.toPrecision(4)));
}
/** A plain quantity with a fixed number of decimals ("15.0", "33.1"). */
export const decimal = (v, digits = 1) => (typeof v === "number" && Number.isFinite(v) ? v.toFixed(digits) : "–");

/** The promotion gate's verdict on a student version (models page, live view): usable or not,
 * why, and on how many held-out frames it was measured against the teacher. A version
 * ``promoted`` although the gate found it not usable says so once: promoted by force, and why
 * the gate would not have. */
export function gateLine(gate, promoted = false) {
  if (!gate) return h("p", { class: "muted small-text", "data-testid": "gate" }, "not measured by the promotion gate");
  const frames = h("span", { class: "muted" }, ` (${count(gate.frames?.length ?? 0, "held-out frame")})`);
  if (promoted && !gate.usable) {
    const why = (gate.reason ?? "").replace(/^Not promoted: /, "").replace(/\.$/, "");
    return h("p", { class: "gate warning", "data-testid": "gate" },
      badge("promoted by force", "forced"), ` although the promotion gate found it not usable${why ? `: ${why}` : ""}.`, frames);
  }
  return h("p", { class: `gate ${gate.usable ? "ok" : "warning"}`, "data-testid": "gate" },
    badge(gate.usable ? "usable" : "not usable"), " ", gate.reason ?? "", frames);
}

/** Whether a version is promoted although the gate found it not usable (``gateLine`` says so). */
export const forced = (model) => Boolean(model.is_promoted && model.gate && !model.gate.usable);

/** A student version's sequential cell and how it measured against the per-frame student (models
 * page): mask IoU on validation frames of videos, and how much of the mask changes from one frame
 * to the next on unlabelled stretches of video — both on what the cell never trained on. Flagged
 * when it is less accurate (by more than 0.01) or less steady; plain when nothing was measured. */
export function sequentialLine(record) {
  if (!record) return h("p", { class: "muted small-text", "data-testid": "sequential" }, "no sequential cell");
  const m = record.measured ?? {};
  const hasAccuracy = typeof m.per_frame_iou === "number" && typeof m.sequential_iou === "number";
  const hasSteadiness = typeof m.per_frame_change === "number" && typeof m.sequential_change === "number";
  const accuracy = hasAccuracy
    ? `mask IoU ${iou(m.sequential_iou)} against the per-frame ${iou(m.per_frame_iou)} on ${count(m.frames, "validation frame")}`
    : "accuracy not measured (no validation frame of a video has 7 frames before it)";
  const steadiness = hasSteadiness
    ? `; the mask changes ${pct(m.sequential_change)} per frame against ${pct(m.per_frame_change)} (${count(m.windows, "stretch", "stretches")} of video)`
    : "";
  const problems = [
    hasAccuracy && m.sequential_iou < m.per_frame_iou - 0.01 ? "less accurate" : "",
    hasSteadiness && m.sequential_change > m.per_frame_change ? "less steady" : "",
  ].filter(Boolean);
  const style = problems.length ? "warning" : hasAccuracy || hasSteadiness ? "ok" : "muted";
  return h("p", { class: `gate ${style}`, "data-testid": "sequential" },
    badge("sequential cell"), ` ${accuracy}${steadiness}.`,
    problems.length ? h("span", { class: "muted" }, ` ${problems.join(" and ")} than the per-frame student: use it where that matters less.`) : "");
}

/** A student version's int8 student (models page): how its masks agree with the float student's
 * on frames it was not calibrated on, and one frame's inference through each on this server
 * (flagged where it is no faster here: a CPU without integer kernels worth the conversions). */
export function int8Line(record) {
  if (!record) return h("p", { class: "muted small-text", "data-testid": "int8" }, "no int8 student");
  const faster = record.float_ms / record.int8_ms;
  const moved = typeof record.keypoint_px === "number" ? `, keypoints ${record.keypoint_px.toFixed(1)} px apart` : "";
  return h("p", { class: `gate ${faster > 1 ? "ok" : "warning"}`, "data-testid": "int8" },
    badge("int8"), ` masks agree with the float student's at IoU ${iou(record.mean_iou)} (${iou(record.min_iou)} at worst) on ${count(record.check_frames, "frame")}${moved}; `,
    `${record.int8_ms.toFixed(1)} ms a frame against ${record.float_ms.toFixed(1)} ms here (${faster.toFixed(1)}× on one thread).`);
}
