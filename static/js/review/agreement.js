// The review page's agreement panel: a frame given to several annotators. An annotator saves
// her own label apart from the others' (every class, tags and attributes; it does not train); a
// reviewer sees every label and how far they agree, class by class, shows one on the canvas, and
// approves one or merges them into the frame's label.

import { api, isReviewer } from "../api.js";
import { classAgreement, count, iou, px } from "../format.js";
import { formatDate, h, toast } from "../ui.js";
import { refreshWork } from "../work.js";
import { commit } from "./history.js";
import { POOL, classOf, colourOf, othersBody, othersFromLabel, retiredOf, selectLayer } from "./layers.js";
import { Mask } from "./mask.js";
import { $, FRAME_ID } from "./page.js";
import { S, changed } from "./state.js";

/** Fetch the frame's labels by several annotators; the panel shows only where there are any. */
export async function loadAgreement() {
  let data;
  try {
    data = await api(`/frames/${FRAME_ID}/overlap`);
  } catch {
    return; // the panel is a convenience: the frame's own label works without it
  }
  if (!data.labels.length) return;
  S.overlap = data;
  S.overlapMine = !isReviewer();
  const own = S.overlapMine ? data.labels[0] : null;
  if (own?.mask_png) { // her own label, as she saved it, is what she goes on from
    const mask = await Mask.fromPng(own.mask_png, S.frame.width, S.frame.height);
    const others = othersFromLabel(own, S.frame.width, S.frame.height);
    S.retired = retiredOf(null, []); // her own label: the frame label's retired parts are not in it
    S.edit = { ...S.edit, mask, keypoints: (own.keypoints ?? []).map((p) => [...p]), ...others, removed: [], maskEdited: false, kpEdited: false, session: null };
    S.labelClean = S.edit;
    selectLayer(S.layer); // the pool again when the edited object was not hers
  }
  render();
  changed();
}

function render() {
  const data = S.overlap;
  const box = $("agreement");
  box.hidden = false;
  if (S.overlapMine) {
    const own = data.labels[0];
    box.replaceChildren(h("h2", {}, "Agreement"),
      h("p", { class: "small-text" }, "This frame is given to several annotators: your label stays apart from theirs (it does not train) until a reviewer approves one or merges them."),
      h("p", { "data-testid": "agreement-own" }, own.labelled ? `Your label is saved (${formatDate(own.updated_at)}); save again to change it.` : "Your label is not saved yet."));
    return;
  }
  const figures = data.mask_iou === null
    ? "two labels are needed to measure agreement"
    : `agreement: mask IoU ${iou(data.mask_iou)} · keypoints ${px(data.keypoint_px)} apart`;
  box.replaceChildren(h("h2", {}, "Agreement"),
    h("p", { "data-testid": "agreement-figures" }, `${data.labelled} of ${count(data.labels.length, "annotator")} labelled · ${figures}`),
    h("ul", { class: "agreement-list" }, ...data.labels.map((label) => h("li", { "data-testid": "agreement-label", "data-username": label.username },
      h("strong", {}, label.username), " ",
      label.labelled ? h("span", { class: "muted" }, formatDate(label.updated_at)) : h("span", { class: "muted" }, "not labelled yet"),
      label.labelled ? h("span", { class: "row" },
        h("button", { type: "button", class: "secondary small", onclick: () => show(label) }, "Show"),
        h("button", { type: "button", class: "primary small", "data-testid": "agreement-approve", onclick: () => settle({ choose: label.user_id }, `${label.username}'s label`) }, "Approve")) : ""))),
    classTable(data),
    differences(data),
    data.labelled >= 2
      ? h("button", { type: "button", class: "secondary", "data-testid": "agreement-merge", title: "A pixel is pool where at least half of the labels say so", onclick: () => settle({ merge: true }, "the merged label") }, "Merge (majority) and approve")
      : "");
}

/** Each class's agreement, the pool's first: the mean over the pairs that drew it. */
function classTable(data) {
  if (data.labelled < 2) return "";
  const swatch = (name) => {
    const node = h("span", { class: "class-swatch", "aria-hidden": "true" });
    node.style.background = colourOf(classOf(name) ?? { name });
    return node;
  };
  const pool = { class: POOL, text: `IoU ${iou(data.mask_iou)} · keypoints ${px(data.keypoint_px)} apart`, pairs: (data.labelled * (data.labelled - 1)) / 2 };
  const rows = [pool, ...(data.classes ?? []).map((c) => ({ class: c.class, text: classAgreement(c), pairs: c.pairs }))];
  return h("table", { class: "agreement-classes", "data-testid": "agreement-classes" },
    h("thead", {}, h("tr", {}, h("th", {}, "class"), h("th", {}, "agreement"), h("th", { title: "Pairs of annotators either of whom drew the class" }, "pairs"))),
    h("tbody", {}, ...rows.map((row) => h("tr", { "data-testid": "agreement-class", "data-class": row.class },
      h("td", {}, swatch(row.class), " ", row.class), h("td", {}, row.text), h("td", {}, String(row.pairs))))));
}

/** The frame's tags and attributes the annotators do not all give alike. */
function differences(data) {
  if (data.labelled < 2 || !data.differ) return "";
  const { tags, attributes } = data.differ;
  const named = (word, names) => (names.length ? `${word}${names.length > 1 ? "s" : ""} ${names.map((n) => `“${n}”`).join(", ")}` : "");
  const parts = [named("tag", tags), named("attribute", attributes)].filter(Boolean);
  return h("p", { class: "small-text", "data-testid": "agreement-differ" },
    parts.length ? `They differ on the frame's ${parts.join(" and ")}.` : "They give the frame the same tags and attributes.");
}

/** One annotator's label on the canvas, every class of it, to look at (an undoable step). */
async function show(label) {
  const mask = await Mask.fromPng(label.mask_png, S.frame.width, S.frame.height);
  const others = othersFromLabel(label, S.frame.width, S.frame.height);
  S.retired = retiredOf(null, []); // the frame label's retired parts stay stored unless removed there
  commit({ ...S.edit, mask, keypoints: (label.keypoints ?? []).map((p) => [...p]), ...others, removed: [], maskEdited: false, kpEdited: false, session: null });
  selectLayer(S.layer);
  toast(`${label.username}'s label is shown.`, "info");
}

async function settle(body, what) {
  try {
    await api(`/frames/${FRAME_ID}/overlap/settle`, { method: "POST", json: body });
  } catch (error) {
    toast(error.message, "error");
    return;
  }
  toast(`Approved ${what}: it is the frame's label now.`, "ok");
  S.leaving = true;
  location.reload();
}

/** An annotator's save of a frame given to several: her own label, kept apart, every class of
 *  it with her tags and attributes. */
export async function saveOwn() {
  const body = { mask_png: await S.edit.mask.toPng(), ...(await othersBody({ all: true })) };
  // Her own label starts from the frame's: what its configuration retired is not hers to send.
  body.tags = body.tags.filter((tag) => !S.retired.tags.includes(tag));
  body.attributes = Object.fromEntries(Object.entries(body.attributes).filter(([name]) => !S.retired.attributes.includes(name)));
  if (S.edit.keypoints.length && !(S.edit.maskEdited && !S.edit.kpEdited)) body.keypoints = S.edit.keypoints;
  try {
    await api(`/frames/${FRAME_ID}/overlap/mine`, { method: "PUT", json: body });
  } catch (error) {
    toast(error.message, "error");
    return false;
  }
  S.labelClean = S.edit;
  changed();
  await loadAgreement();
  refreshWork();
  toast("Your label is saved, apart from the other annotators'.", "ok");
  return true;
}
