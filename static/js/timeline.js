// A weld run over time: a strip of its frames coloured by review status and confidence, the
// pool's area, length and width over the run (a click opens that frame), and propagation.

import { api, ApiError, isReviewer, jobFromButton, SAM2_PROBLEM } from "./api.js";
import { leastSpan, lineChart } from "./chart.js";
import { count, decimal, mmPerPx } from "./format.js";
import { renderStability } from "./stability.js";
import { markTags, renderClassSeries } from "./timeline_classes.js";
import { h, toast } from "./ui.js";

const SEQUENCE_ID = Number(document.getElementById("timeline").dataset.sequenceId);
const $ = (id) => document.getElementById(id);
let timeline = null;

const REVIEWED = { accepted: "accepted", corrected: "corrected", rejected: "rejected" };

/** A proposal's confidence as a colour from red (0) through amber to green (1). */
function confidenceColour(value) {
  const hue = Math.round(120 * Math.min(1, Math.max(0, value)));
  return `hsl(${hue} 70% 45%)`;
}

function reviewUrl(frameId) {
  return `/frames/${frameId}?sequence_id=${SEQUENCE_ID}&order=frame_index&status=all`;
}

function renderStrip() {
  const strip = $("strip");
  strip.replaceChildren(...timeline.frames.map((row, i) => {
    const reviewed = REVIEWED[row.status];
    const cell = h("a", {
      // a frame the charts count (a proposal shown, with a confidence or not: a student's has
      // none) looks proposed; only a frame with no proposal at all is grey
      class: `cell ${reviewed ?? (row.source ? "proposed" : "none")}`,
      href: reviewUrl(row.frame_id),
      "data-testid": "strip-cell",
      "data-frame-id": String(row.frame_id),
      "data-status": row.status,
      title: [`#${row.frame_id}`, row.frame_index !== null ? `index ${row.frame_index}` : `position ${i + 1}`,
        row.status, row.source ? `from ${row.source}` : "no proposal",
        row.confidence !== null ? `confidence ${decimal(row.confidence, 2)}` : ""].filter(Boolean).join(" · "),
    });
    if (!reviewed && row.confidence !== null) cell.style.background = confidenceColour(row.confidence);
    return cell;
  }));
  markTags(timeline);
}

function renderCharts() {
  const rows = timeline.frames;
  const mm = timeline.mm_per_px !== null;
  const timed = rows.every((r) => r.timestamp_s !== null);
  const x = (row, i) => (timed ? row.timestamp_s : row.frame_index ?? i);
  const xLabel = timed ? "s" : "frame";
  const onPick = (value) => {
    let best = 0;
    rows.forEach((row, i) => { if (Math.abs(x(row, i) - value) < Math.abs(x(rows[best], best) - value)) best = i; });
    location.href = reviewUrl(rows[best].frame_id);
  };
  const xs = rows.map((r, i) => x(r, i)).filter(Number.isFinite);
  const xDomain = xs.length ? [Math.min(...xs), Math.max(...xs)] : null; // every chart: one x range
  const quantity = (title, key, unit) => lineChart({
    title, unit, xLabel, xDomain, width: 420, height: 180, onPick, minSpan: leastSpan(rows.map((r) => r[key]), unit),
    series: [
      { name: "every frame", colour: "#1c7ed6", points: rows.map((r, i) => [x(r, i), r[key] ?? NaN]) },
      { name: "reviewed", colour: "#2f9e44", dots: true, points: rows.map((r, i) => [x(r, i), r.source === "label" ? r[key] ?? NaN : NaN]) },
    ],
  });
  const charts = mm
    ? [quantity("Pool area", "area_mm2", "mm²"), quantity("Length along travel", "length_mm", "mm"), quantity("Width across travel", "width_mm", "mm")]
    : [quantity("Pool area", "area_px", "px²"), quantity("Length along travel", "length_px", "px"), quantity("Width across travel", "width_px", "px")];
  const confidence = lineChart({
    title: "Proposal confidence", xLabel, xDomain, width: 420, height: 180, domain: [0, 1], onPick,
    series: [{ name: "confidence", colour: "#e8590c", points: rows.map((r, i) => [x(r, i), r.confidence ?? NaN]) }],
  });
  $("charts").replaceChildren(...[...charts, confidence].map((chart) => h("figure", { class: "chart-box" }, chart)));
  renderClassSeries(timeline, { x, xLabel, xDomain, onPick });
  const withPool = rows.filter((r) => r.area_px !== null).length;
  $("geometry-note").textContent = `${count(withPool, "frame")} of ${rows.length} with a pool (reviewed label, else the proposal shown). `
    + (timeline.travel_deg !== null ? `Length is measured along ${decimal(timeline.travel_deg, 1)}° (${timeline.travel_source}), width across it. ` : "")
    + (mm ? `Scale: ${mmPerPx(timeline.mm_per_px)} mm per pixel.` : "No scale set: pixels (set mm per pixel in the weld run's Edit dialog for millimetres).");
}

function renderHead() {
  if (!timeline) return;
  $("run-name").textContent = timeline.name;
  document.title = `${timeline.name} · weldpool`;
  const p = timeline.process;
  const parts = [
    p.wire_feed_m_min !== null ? `wire ${p.wire_feed_m_min} m/min` : "",
    p.voltage_v !== null ? `${p.voltage_v} V` : "",
    p.current_a !== null ? `${p.current_a} A` : "",
    p.arc_length_correction_pct !== null ? `arc length ${p.arc_length_correction_pct} %` : "",
    p.robot_speed_cm_min !== null ? `travel ${p.robot_speed_cm_min} cm/min` : "",
    p.synergic_law ?? "", p.joint_type ?? "",
    timeline.mm_per_px !== null ? `scale ${mmPerPx(timeline.mm_per_px)} mm/px` : "",
  ].filter(Boolean);
  $("run-process").textContent = `${count(timeline.frames.length, "frame")}` + (parts.length ? ` · ${parts.join(" · ")}` : " · no process parameters yet");
  const reviewed = timeline.frames.filter((r) => r.source === "label" && r.area_px !== null);
  Object.assign($("embed-run"), { disabled: Boolean(SAM2_PROBLEM), title: SAM2_PROBLEM || "Compute SAM2's embedding of every frame now, so that the first click on any frame is as quick as the later ones" });
  const button = $("propagate-run");
  button.disabled = reviewed.length === 0 || Boolean(SAM2_PROBLEM) || !isReviewer();
  button.title = SAM2_PROBLEM || (!isReviewer() ? "A reviewer propagates: it writes proposals over the whole run." : reviewed.length ? `Carry the ${count(reviewed.length, "reviewed mask")} of this run to its other frames (SAM2 video)` : "Accept or correct a frame of this run first: propagation starts from reviewed masks.");
}

async function load() {
  try {
    timeline = await api(`/sequences/${SEQUENCE_ID}/geometry`);
  } catch (error) {
    $("charts").replaceChildren(h("p", { class: "error" }, error instanceof ApiError ? error.message : String(error)));
    // Nothing to act on: no run (or no answer), so its buttons and its CSV are not offered.
    for (const id of ["embed-run", "propagate-run"]) Object.assign($(id), { disabled: true, title: "" });
    $("geometry-csv").hidden = true;
    document.body.dataset.ready = "1";
    return;
  }
  $("geometry-csv").hidden = false;
  renderHead();
  renderStrip();
  renderCharts();
  await renderStability(SEQUENCE_ID, timeline, reviewUrl);
  document.body.dataset.ready = "1";
}

/** A job started from one of the page's buttons; says how it ended. */
async function runFromButton(button, start, working, done) {
  try {
    const job = await jobFromButton(button, start, working);
    const ok = job.status === "succeeded";
    $("job-state").textContent = ok ? `${done}: ${job.message}.` : `The job ${job.status}: ${job.error ?? job.message ?? ""}`;
    toast($("job-state").textContent, ok ? "ok" : "error");
    if (ok) await load();
  } catch (error) {
    toast(error.message, "error");
  } finally {
    renderHead();
  }
}

$("propagate-run").addEventListener("click", () => {
  const from = timeline.frames.filter((r) => r.source === "label" && r.area_px !== null).map((r) => r.frame_id).slice(0, 64);
  runFromButton($("propagate-run"), () => api(`/sequences/${SEQUENCE_ID}/propagate`, { method: "POST", json: { from_frame_ids: from, direction: "both" } }),
    "Propagating", "Propagation done");
});

$("embed-run").addEventListener("click", () => {
  runFromButton($("embed-run"), () => api(`/sequences/${SEQUENCE_ID}/embeddings`, { method: "POST" }), "Embedding", "Embeddings ready");
});

load();
