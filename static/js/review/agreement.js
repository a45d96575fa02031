// The review page's agreement panel: a frame given to several annotators. An annotator saves
// her own label apart from the others' (it does not train); a reviewer sees every label and how
// far they agree, shows one on the canvas, and approves one or merges them into the frame's label.

import { api, isReviewer } from "../api.js";
import { count, iou, px } from "../format.js";
import { formatDate, h, toast } from "../ui.js";
import { refreshWork } from "../work.js";
import { commit } from "./history.js";
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
    S.edit = { ...S.edit, mask, keypoints: (own.keypoints ?? []).map((p) => [...p]), maskEdited: false, kpEdited: false, session: null };
    S.labelClean = S.edit;
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
    data.labelled >= 2
      ? h("button", { type: "button", class: "secondary", "data-testid": "agreement-merge", title: "A pixel is pool where at least half of the labels say so", onclick: () => settle({ merge: true }, "the merged label") }, "Merge (majority) and approve")
      : "");
}

/** One annotator's label on the canvas, to look at (an undoable step). */
async function show(label) {
  const mask = await Mask.fromPng(label.mask_png, S.frame.width, S.frame.height);
  commit({ ...S.edit, mask, keypoints: (label.keypoints ?? []).map((p) => [...p]), maskEdited: false, kpEdited: false, session: null });
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

/** An annotator's save of a frame given to several: her own label, kept apart. */
export async function saveOwn() {
  const body = { mask_png: await S.edit.mask.toPng() };
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
