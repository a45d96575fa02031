// A weld run's stability on its timeline: the stored signature (level, spread, trend, CV,
// oscillation), its unstable stretches marked on the frame strip and listed with their frames,
// and the width's rolling coefficient of variation against the threshold.

import { api, ApiError } from "./api.js";
import { lineChart } from "./chart.js";
import { count, decimal } from "./format.js";
import { h } from "./ui.js";

const figure = (f, unit, digits = 2) => (f.median === null ? "–"
  : `${decimal(f.median, digits)} ${unit} (IQR ${decimal(f.q1, digits)}–${decimal(f.q3, digits)})`
    + (f.trend_pct !== null ? `, trend ${f.trend_pct >= 0 ? "+" : ""}${decimal(f.trend_pct, 1)} % over the run` : ""));

function summary(sig) {
  const len = sig.unit === "mm" ? "mm" : "px";
  const area = sig.unit === "mm" ? "mm²" : "px²";
  const osc = sig.oscillation;
  const rows = [
    ["Width", figure(sig.width, len)],
    ["Length", figure(sig.length, len)],
    ["Area", figure(sig.area, area, 1)],
    ["Width CV", sig.width_cv === null ? "–" : `${decimal(100 * sig.width_cv, 1)} %`],
    ["Oscillation", osc ? `${decimal(osc.hz, 2)} Hz, strength ${decimal(osc.strength, 2)}` : "– (needs frame times)"],
    ["Unstable", sig.stretches.length ? count(sig.stretches.length, "stretch", "stretches") : "none found"],
  ];
  return h("dl", { class: "signature", "data-testid": "signature" },
    ...rows.flatMap(([k, v]) => [h("dt", {}, k), h("dd", {}, v)]));
}

function stretchList(sig, reviewUrl) {
  return h("ul", { class: "stretches", "data-testid": "unstable-stretches" }, ...sig.stretches.map((s, i) => h("li", {},
    h("a", { href: reviewUrl(s.frame_ids[0]), "data-testid": "unstable-stretch" },
      `Stretch ${i + 1}: ` + (s.start_frame_index !== null && s.end_frame_index !== null
        ? `frames ${s.start_frame_index}–${s.end_frame_index}` : `frames ${s.start_position}–${s.end_position} of the run`)
      + (s.start_s !== null ? ` (${decimal(s.start_s, 2)}–${decimal(s.end_s, 2)} s)` : "")),
    ` · ${count(s.frame_ids.length, "frame")}, rolling CV up to ${decimal(100 * s.peak_cv, 1)} %`)));
}

/** Marks the strip's unstable cells, and the frame the URL asks for (`?frame=`). */
function markStrip(sig) {
  const unstable = new Set(sig.stretches.flatMap((s) => s.frame_ids));
  const wanted = Number(new URLSearchParams(location.search).get("frame"));
  for (const cell of document.querySelectorAll("[data-testid=strip-cell]")) {
    const id = Number(cell.dataset.frameId);
    cell.classList.toggle("unstable", unstable.has(id));
    if (id === wanted) { cell.classList.add("wanted"); cell.scrollIntoView({ block: "nearest", inline: "center" }); }
  }
}

/** The stability section of the timeline (`timeline`: the geometry the page loaded). */
export async function renderStability(sequenceId, timeline, reviewUrl) {
  const box = document.getElementById("stability");
  let sig;
  try {
    sig = await api(`/sequences/${sequenceId}/signature`);
  } catch (error) {
    box.replaceChildren(h("p", { class: "error" }, error instanceof ApiError ? error.message : String(error)));
    return;
  }
  const times = new Map(timeline.frames.map((r, i) => [r.frame_id, r.timestamp_s ?? r.frame_index ?? i]));
  const timed = timeline.frames.every((r) => r.timestamp_s !== null);
  const chart = lineChart({
    title: "Width rolling CV", unit: "%", xLabel: timed ? "s" : "frame", width: 420, height: 180,
    onPick: (value) => {
      let best = sig.rolling_cv[0];
      for (const e of sig.rolling_cv) if (Math.abs(times.get(e.frame_id) - value) < Math.abs(times.get(best.frame_id) - value)) best = e;
      if (best) location.href = reviewUrl(best.frame_id);
    },
    series: [
      { name: "rolling CV", colour: "#c2255c", points: sig.rolling_cv.map((e) => [times.get(e.frame_id), e.cv === null ? NaN : 100 * e.cv]) },
      { name: "8 % limit", colour: "#868e96", points: sig.rolling_cv.map((e) => [times.get(e.frame_id), 8]) },
    ],
  });
  const note = sig.unit_note ? [h("p", { class: "muted small-text" }, sig.unit_note)] : [];
  box.replaceChildren(
    h("div", { class: "stability-row" }, summary(sig), h("figure", { class: "chart-box" }, chart)),
    ...note,
    sig.stretches.length ? stretchList(sig, reviewUrl) : h("p", { class: "muted" }, "No unstable stretch: the width's rolling CV stays under 8 %."),
    h("p", { class: "muted small-text" }, h("a", { href: `/?sequence_id=${sequenceId}&unstable=true&status=all` }, "Unstable frames in the frame list"), " · ",
      h("a", { href: "/process" }, "Compare runs on the process map")),
  );
  markStrip(sig);
}
