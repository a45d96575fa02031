// The classes a student version learned beside the pool (models page): per class, its figure
// from the promotion gate (on the held-out frames that have the class labelled), the incumbent's
// on the same frames where the gate compared it (and the difference), and from its training's
// validation: IoU for mask and instances classes, point distance for points classes.
// Reported only: the pool alone decides a promotion.
import { h } from "./ui.js";
import { count, iou, px } from "./format.js";

/** One class's figure: IoU or distance, and on how many frames unless ``frames`` is false
 * (the incumbent's: the same frames as the gate's); "–" where none had it. */
function figure(row, frames = true) {
  if (!row || !row.frames) return "–";
  const value = row.kind === "points" ? px(row.distance_px) : `IoU ${iou(row.IoU)}`;
  const on = frames ? ` on ${count(row.frames, "frame")}` : "";
  const missed = row.missed ? ` · ${count(row.missed, "point")} not found` : "";
  return `${value}${on}${missed}`;
}

/** This version's figure less the incumbent's, signed, with whether it is better (a higher
 * IoU, a shorter distance); none where either has no figure. */
function difference(mine, theirs) {
  const key = mine?.kind === "points" ? "distance_px" : "IoU";
  const [a, b] = [mine?.[key], theirs?.[key]];
  if (!mine?.frames || !theirs?.frames || typeof a !== "number" || typeof b !== "number") {
    return h("td", { class: "num" }, "–");
  }
  const delta = a - b;
  const text = key === "IoU" ? iou(Math.abs(delta)) : px(Math.abs(delta));
  const sign = delta > 0 ? "+" : delta < 0 ? "−" : "±";
  const better = key === "IoU" ? delta > 0 : delta < 0;
  const verdict = delta === 0 ? "same" : better ? "better" : "worse";
  return h("td", { class: `num ${verdict}`, "data-verdict": verdict, title: `${verdict} than the incumbent` }, sign + text);
}

/** The learned classes' table of a version, or nothing for a pool-only version. */
export function classesTable(model) {
  const learned = model.config?.student?.classes ?? [];
  if (!learned.length) return "";
  const gate = model.gate?.classes ?? {};
  const validation = model.metrics?.classes ?? {};
  const theirs = model.gate?.incumbent_classes; // absent: no incumbent at the gate
  const incumbent = model.gate?.incumbent ?? "incumbent";
  const compared = theirs ? [
    h("th", { title: `${incumbent}, promoted when this version was measured, on the same frames ("–": it did not learn this class)` }, `${incumbent} (incumbent)`),
    h("th", { title: "This version's gate figure less the incumbent's" }, "difference"),
  ] : [];
  return h("table", { class: "metrics classes", "data-testid": "model-classes" },
    h("thead", {}, h("tr", {},
      h("th", {}, "learned class"), h("th", {}, "kind"),
      h("th", { title: "The promotion gate's held-out frames that have this class labelled (not part of the pool's rule)" }, "gate"),
      ...compared,
      h("th", { title: "The training's validation frames that have this class labelled" }, "validation"))),
    h("tbody", {}, learned.map((c) => h("tr", { "data-class": c.name },
      h("th", {}, c.name + (c.points?.length ? ` (${c.points.join(", ")})` : "")),
      h("td", {}, c.kind),
      h("td", { class: "num" }, figure(gate[c.name])),
      ...(theirs ? [h("td", { class: "num" }, figure(theirs[c.name], false)), difference(gate[c.name], theirs[c.name])] : []),
      h("td", { class: "num" }, figure(validation[c.name]))))));
}
