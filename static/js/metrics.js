// The metrics page: GET /api/v1/metrics as charts and tables.

import { api } from "./api.js";
import { lineChart } from "./chart.js";
import { classAgreement, count, iou, pct, px } from "./format.js";
import { peopleSection } from "./people.js";
import { h } from "./ui.js";

const root = document.getElementById("metrics");

function learningCurve(student) {
  if (!student.length) {
    return h("p", { class: "muted" }, "No student version yet: train one on the models page.");
  }
  const points = (key) => student.filter((v) => typeof v[key] === "number").map((v) => [v.train_label_count, v[key]]);
  return h("div", { class: "charts" },
    lineChart({ title: "Student mIoU", xLabel: "labels", domain: [0, 1], width: 420, height: 200,
      series: [{ name: "mIoU", colour: "#1971c2", points: points("mIoU") }] }),
    lineChart({ title: "Student mED", xLabel: "labels", unit: "px", width: 420, height: 200,
      series: [{ name: "mED", colour: "#d9480f", points: points("mED") }] }));
}

function table(headers, rows, testid) {
  return h("table", { class: "table", "data-testid": testid },
    h("thead", {}, h("tr", {}, ...headers.map((text) => h("th", {}, text)))),
    h("tbody", {}, ...rows.map((cells) => h("tr", {}, ...cells.map((c) => h("td", {}, c))))));
}

/** Per class and frame tag: the frames labelled with it, its objects, the frames approved. */
function classesSection(figures) {
  if (!figures) return "";
  const kind = (c) => (c.configured ? c.kind : "no longer configured");
  return h("section", { "data-testid": "class-figures" },
    h("h2", {}, "Classes and tags"),
    h("p", { class: "muted small-text" },
      "Per class, the frames whose label holds it (the pool: a pool mask), its objects, and the frames among them whose label is approved (with the review stage off, every saved label). ",
      h("a", { href: "/api/v1/metrics/classes?format=csv", download: "", "data-testid": "classes-csv" }, "CSV")),
    table(["class", "kind", "frames labelled", "objects", "reviewed"],
      figures.classes.map((c) => [c.configured ? h("a", { href: `/?class=${encodeURIComponent(c.name)}&status=all&order=id` }, c.name) : c.name, kind(c), String(c.frames), String(c.objects), String(c.reviewed)]),
      "class-table"),
    h("h3", {}, "Frame tags"),
    figures.tags.length
      ? table(["frame tag", "frames tagged"],
        figures.tags.map((t) => [h("a", { href: `/?tag=${encodeURIComponent(t.name)}&status=all&order=id` }, t.name), String(t.frames)]),
        "tag-table")
      : h("p", { class: "muted" }, "No frame tags are configured (Label configuration page)."));
}

function render(data) {
  const teacher = data.teacher;
  const review = data.review;
  const labels = review.labels;
  root.replaceChildren(
    h("h2", {}, "Student learning curve"),
    learningCurve(data.student),
    data.student.length ? table(["version", "labels", "mIoU", "mED", ""],
      data.student.map((v) => [v.name, String(v.train_label_count), iou(v.mIoU), px(v.mED), v.promoted ? "promoted" : ""]),
      "student-table") : "",
    h("h2", {}, "Teacher against reviewed masks"),
    teacher.overall.frames
      ? table(["sequence", "frames", "mIoU", "Q1", "median", "Q3"],
        [...teacher.by_sequence, { sequence: "all", ...teacher.overall }].map((r) => [
          r.sequence ?? "(no sequence)", String(r.frames), iou(r.mIoU), iou(r.q1), iou(r.median), iou(r.q3)]),
        "teacher-table")
      : h("p", { class: "muted" }, teacher.left_out
        ? "Every reviewed frame kept the teacher's mask unchanged: nothing fair to measure the teacher on yet."
        : "No reviewed frame has a teacher proposal yet."),
    teacher.left_out ? h("p", { class: "muted small-text", "data-testid": "teacher-fair-note" },
      `These figures leave out the ${count(teacher.left_out, "label")} accepted unchanged from the teacher (they are its own masks, IoU 1.000 by construction), as the promotion gate does. `,
      `With them: mIoU ${iou(teacher.including_unchanged.mIoU)} over ${count(teacher.including_unchanged.frames, "frame")}.`) : "",
    h("h2", {}, "Agreement between annotators"),
    data.agreement?.length
      ? table(["sequence", "frames", "mask IoU", "keypoints apart", "other classes", "tags differ"],
        data.agreement.map((r) => [r.sequence ?? "(no sequence)", String(r.frames), iou(r.mask_iou), px(r.keypoint_px),
          (r.classes ?? []).map((c) => `${c.class}: ${classAgreement(c)} (${count(c.frames, "frame")})`).join("; ") || "–",
          `${r.tags_differ ?? 0} of ${count(r.frames, "frame")}`]),
        "agreement-table")
      : h("p", { class: "muted" }, "No frame has been labelled by two annotators yet (Frames page: select frames, “Give to several…”)."),
    classesSection(data.classes),
    h("h2", {}, "Review"),
    h("p", { "data-testid": "acceptance" },
      `Current labels: ${labels.accepted} accepted, ${labels.corrected} corrected, ${labels.rejected} rejected. `,
      review.teacher_acceptance_rate === null
        ? "No teacher proposal has been reviewed yet."
        : `Reviewers accepted ${pct(review.teacher_acceptance_rate)} of the ${review.teacher_reviewed} teacher proposals they reviewed as they were.`),
    data.policy ? h("p", { "data-testid": "policy" }, "Shown for review: ", h("strong", {}, data.policy.chosen), ` — ${data.policy.reason}`) : "",
    review.by_source?.length
      ? table(["source", "reviewed", "accepted", "corrected", "rejected", "unchanged", "acceptance"],
        review.by_source.map((s) => [s.source, String(s.reviewed), String(s.accepted), String(s.corrected), String(s.rejected), String(s.unchanged), pct(s.acceptance_rate)]),
        "source-table")
      : "",
    review.over_time.length
      ? h("section", { "data-testid": "saves-per-day" }, h("h3", {}, "Saves per day"),
        h("p", { class: "muted small-text", "data-testid": "review-table-note" },
          "Every save counts here, so a frame corrected twice counts twice; the totals above count each frame's current label once."),
        table(["day", "accepted", "corrected", "rejected"],
          review.over_time.map((d) => [d.day, String(d.accepted), String(d.corrected), String(d.rejected)]),
          "review-table"))
      : "",
    h("p", { class: "muted" }, `${data.queue.scored_frames} frames have an uncertainty score in the review queue.`));
}

peopleSection(document.getElementById("people"));

api("/metrics").then(render).catch((error) => {
  root.replaceChildren(h("p", { class: "error" }, error.message));
});
