// Per-person figures (GET /api/v1/metrics/people) as a table with a period filter and its CSV:
// on the metrics page (each role sees the rows the route allows) and the users page (admins).

import { api, query } from "./api.js";
import { count, decimal, duration, iou, pct, px } from "./format.js";
import { h } from "./ui.js";

const PERIODS = [["all", "all time"], ["1", "last 24 hours"], ["7", "last 7 days"], ["30", "last 30 days"]];

function since(period) {
  if (period === "all") return {};
  return { since: new Date(Date.now() - Number(period) * 86_400_000).toISOString() };
}

function row(p) {
  const decided = p.decisions
    ? `${p.approved} approved · ${p.corrected_and_approved} corrected · ${p.returned} sent back`
    : "–";
  return h("tr", { "data-testid": "people-row", "data-username": p.username },
    h("td", {}, h("strong", {}, p.username), " ", h("span", { class: "muted" }, p.role)),
    h("td", { class: "num" }, String(p.labels_saved)),
    h("td", { class: "num" }, p.submitted ? `${p.sent_back} of ${p.submitted} · ${pct(p.sent_back_rate)}` : "–"),
    // Under a minute of active time says nothing about a pace (a script's saves, a first try).
    h("td", { class: "num", title: `${decimal(p.active_hours, 2)} active hours` }, p.active_hours * 3600 < 60 ? "–" : decimal(p.frames_per_hour)),
    h("td", { class: "num" }, p.active_hours * 3600 < 60 ? "–" : duration(p.seconds_per_frame)),
    h("td", { class: "num", title: count(p.compared_with_approved, "submission") + " compared" }, iou(p.iou_vs_approved)),
    h("td", { class: "num" }, px(p.keypoint_px_vs_approved)),
    h("td", {}, decided),
    h("td", { class: "num" }, duration(p.turnaround_median_s)));
}

/** Fill `root` with the people table and keep it in step with its period filter. */
export function peopleSection(root) {
  const select = h("select", { "data-testid": "people-period", "aria-label": "Period" },
    ...PERIODS.map(([value, words]) => h("option", { value }, words)));
  const csv = h("a", { href: "/api/v1/metrics/people?format=csv", "data-testid": "people-csv", download: "" }, "CSV");
  const body = h("tbody", {}, h("tr", {}, h("td", { colspan: "9", class: "muted" }, "Loading…")));
  const table = h("table", { class: "table people", "data-testid": "people-table" },
    h("thead", {}, h("tr", {}, ...["person", "labels saved", "sent back", "frames / h", "time / frame", "IoU vs approved", "keypoints vs approved", "decisions", "turnaround"].map((t) => h("th", {}, t)))),
    body);
  const note = h("p", { class: "muted small-text", "data-testid": "people-note" },
    "Active time counts the gap before each save when it is at most 5 minutes (a longer gap is a pause). ",
    "IoU and keypoint distance compare each submission with the label the reviewer then approved (sent-back ones included). ",
    "Turnaround: the median time from a submission to a reviewer's decision.");
  async function load() {
    const params = { ...since(select.value) };
    csv.href = `/api/v1/metrics/people${query({ ...params, format: "csv" })}`;
    try {
      const answer = await api(`/metrics/people${query(params)}`);
      body.replaceChildren(...(answer.people.length ? answer.people.map(row) : [h("tr", {}, h("td", { colspan: "9", class: "muted" }, "Nobody yet."))]));
    } catch (error) {
      body.replaceChildren(h("tr", {}, h("td", { colspan: "9", class: "error" }, error.message)));
    }
    root.dataset.ready = "1";
  }
  select.addEventListener("change", load);
  root.replaceChildren(h("div", { class: "filters" }, h("label", {}, "Period ", select), csv), table, note);
  return load();
}
