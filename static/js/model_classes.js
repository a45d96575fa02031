// The classes a student version learned beside the pool (models page): per class, its figure
// from the promotion gate (on the held-out frames that have the class labelled) and from its
// training's validation: IoU for mask and instances classes, point distance for points classes.
// Reported only: the pool alone decides a promotion.
import { h } from "./ui.js";
import { count, iou, px } from "./format.js";

/** One class's figure: IoU or distance, and on how many frames ("–" where none had it). */
function figure(row) {
  if (!row || !row.frames) return "–";
  const value = row.kind === "points" ? px(row.distance_px) : `IoU ${iou(row.IoU)}`;
  const missed = row.missed ? ` · ${count(row.missed, "point")} not found` : "";
  return `${value} on ${count(row.frames, "frame")}${missed}`;
}

/** The learned classes' table of a version, or nothing for a pool-only version. */
export function classesTable(model) {
  const learned = model.config?.student?.classes ?? [];
  if (!learned.length) return "";
  const gate = model.gate?.classes ?? {};
  const validation = model.metrics?.classes ?? {};
  return h("table", { class: "metrics classes", "data-testid": "model-classes" },
    h("thead", {}, h("tr", {},
      h("th", {}, "learned class"), h("th", {}, "kind"),
      h("th", { title: "The promotion gate's held-out frames that have this class labelled (not part of the pool's rule)" }, "gate"),
      h("th", { title: "The training's validation frames that have this class labelled" }, "validation"))),
    h("tbody", {}, learned.map((c) => h("tr", { "data-class": c.name },
      h("th", {}, c.name + (c.points?.length ? ` (${c.points.join(", ")})` : "")),
      h("td", {}, c.kind),
      h("td", { class: "num" }, figure(gate[c.name])),
      h("td", { class: "num" }, figure(validation[c.name]))))));
}
