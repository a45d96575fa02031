// The other classes over a weld run: a chosen class's series (a mask or instances class's
// summed area or object count, a points class's x or y) beside the pool's charts, from the
// reviewed labels; and the frames' tags marked on the strip (their names on hover).

import { lineChart } from "./chart.js";
import { count } from "./format.js";
import { h } from "./ui.js";

const $ = (id) => document.getElementById(id);

/** Every series the run's classes offer: [{key, label, unit, value(row)}]; a frame without a
 * label has no value, a labelled frame without the class counts 0 (area and objects). */
export function classSeries(timeline) {
  const mm = timeline.mm_per_px !== null;
  const labelled = (row) => row.source === "label";
  const out = [];
  for (const c of timeline.classes) {
    const of = (row) => row.classes?.[c.name];
    if (c.kind === "points") {
      const names = c.point_names ?? [...new Set(timeline.frames.flatMap((r) => Object.keys(of(r)?.points ?? {})))];
      for (const point of names) {
        for (const [axis, i] of [["x", 0], ["y", 1]]) {
          out.push({ key: `${c.name}|${point}|${axis}`, label: `${c.name}: ${point} ${axis}`, unit: "px",
            value: (row) => of(row)?.points?.[point]?.[i] ?? NaN });
        }
      }
    } else {
      out.push({ key: `${c.name}|area`, label: `${c.name}: area`, unit: mm ? "mm²" : "px²",
        value: (row) => (labelled(row) ? (mm ? of(row)?.area_mm2 : of(row)?.area_px) ?? 0 : NaN) });
    }
    out.push({ key: `${c.name}|count`, label: `${c.name}: objects`, unit: "",
      value: (row) => (labelled(row) ? of(row)?.count ?? 0 : NaN) });
  }
  return out;
}

/** The class series select and its chart, drawn with the pool's charts' x axis. */
export function renderClassSeries(timeline, { x, xLabel, xDomain, onPick }) {
  const choices = classSeries(timeline);
  const select = $("class-series");
  $("class-series-field").hidden = !choices.length;
  if (!choices.length) { $("class-chart").replaceChildren(); return; }
  const kept = select.value;
  select.replaceChildren(...choices.map((s) => h("option", { value: s.key }, s.label)));
  select.value = choices.some((s) => s.key === kept) ? kept : choices[0].key;
  const draw = () => {
    const chosen = choices.find((s) => s.key === select.value) ?? choices[0];
    const rows = timeline.frames;
    $("class-chart").replaceChildren(h("figure", { class: "chart-box" }, lineChart({
      title: chosen.label, unit: chosen.unit, xLabel, xDomain, width: 420, height: 180, onPick,
      series: [{ name: chosen.label, colour: "#0c8599", dots: true, points: rows.map((r, i) => [x(r, i), chosen.value(r)]) }],
    })));
  };
  select.onchange = draw;
  draw();
}

/** The strip's cells of tagged frames marked (the chosen tag's, or any tag's), their tags in
 * their titles; a note counts each tag's frames. */
export function markTags(timeline) {
  const field = $("tag-mark");
  const tags = timeline.frame_tags;
  const counts = Object.fromEntries(tags.map((t) => [t, timeline.frames.filter((r) => r.tags.includes(t)).length]));
  const tagged = timeline.frames.filter((r) => r.tags.length).length;
  $("tag-field").hidden = !tags.length;
  if (!tags.length) return;
  const kept = field.value;
  field.replaceChildren(h("option", { value: "" }, "any tag"), ...tags.map((t) => h("option", { value: t }, `${t} (${counts[t]})`)));
  field.value = tags.includes(kept) ? kept : "";
  const byId = new Map(timeline.frames.map((r) => [String(r.frame_id), r]));
  const mark = () => {
    for (const cell of document.querySelectorAll("[data-testid=strip-cell]")) {
      const row = byId.get(cell.dataset.frameId);
      const on = row.tags.length > 0 && (!field.value || row.tags.includes(field.value));
      cell.classList.toggle("tagged", on);
      cell.dataset.tags = row.tags.join(", ");
      cell.title = cell.title.replace(/ · tags: .*$/, "") + (row.tags.length ? ` · tags: ${row.tags.join(", ")}` : "");
    }
  };
  field.onchange = mark;
  mark();
  $("tag-note").textContent = `${count(tagged, "frame")} tagged: ${tags.map((t) => `${t} ${counts[t]}`).join(", ")}.`;
}
