// Keypoints: the list, removing one, and the validation mode for keypoints placed by hand.

import { api } from "../api.js";
import { formatDate, h, toast } from "../ui.js";
import { setMaskVisible } from "./display.js";
import { changed, commit, manualDirty } from "./history.js";
import { $, FRAME_ID, K } from "./page.js";
import { renderFrameInfo } from "./review.js";
import { S } from "./state.js";
import { enableTools, setTool } from "./tools.js";

// --- side panel -----------------------------------------------------------------------------

export function renderKeypointList() {
  const list = $("keypoint-list");
  const points = S.validation ? S.edit.manual : S.edit.keypoints;
  list.replaceChildren(...points.map(([x, y], i) => h("li", { class: i === S.stage.selected ? "selected" : "" },
    h("span", {}, `${x.toFixed(1)}, ${y.toFixed(1)}`),
    h("button", { type: "button", class: "quiet tiny-btn", title: "Remove this keypoint", onclick: () => deleteKeypoint(i) }, "×"))));
  if (!points.length) list.append(h("li", { class: "muted plain" }, S.validation ? "none placed yet" : "none"));
  if (S.stage.dimKeypoints) list.append(h("li", { class: "muted plain" }, "The mask changed: the keypoints are recomputed from it on save, unless you move one."));
}

export function renderManualCount() {
  $("manual-count").textContent = `${S.edit.manual.length} of ${K} placed`;
  $("save-validation").disabled = S.edit.manual.length !== K || !manualDirty();
}

export function deleteKeypoint(index) {
  if (S.validation) {
    commit({ ...S.edit, manual: S.edit.manual.filter((_, i) => i !== index) });
  } else {
    commit({ ...S.edit, keypoints: S.edit.keypoints.filter((_, i) => i !== index), kpEdited: true });
  }
  S.stage.selected = -1;
  changed();
}

export async function saveValidation() {
  try {
    const saved = await api(`/frames/${FRAME_ID}/validation-keypoints`, { method: "PUT", json: { keypoints: S.edit.manual } });
    S.manualClean = S.edit.manual;
    S.frame.split = "validation";
    renderFrameInfo();
    $("validation-state").textContent = `Saved ${saved.keypoints.length} keypoints by hand (${formatDate(saved.updated_at)}); this frame is in the validation split.`;
    toast("Validation keypoints saved.", "ok");
    changed();
  } catch (error) {
    toast(error.message, "error");
  }
}

export function toggleValidation() {
  S.validation = !S.validation;
  document.body.classList.toggle("validating", S.validation);
  $("validation-toggle").setAttribute("aria-pressed", String(S.validation));
  $("validation-toggle").classList.toggle("active", S.validation);
  $("validation-panel").hidden = !S.validation;
  enableTools();
  S.stage.selected = -1;
  if (S.validation) {
    S.toolBeforeValidation = S.tool;
    S.maskBeforeValidation = $("show-mask").checked;
    setMaskVisible(false);
    setTool("keypoint");
  } else {
    setMaskVisible(S.maskBeforeValidation);
    setTool(S.toolBeforeValidation);
  }
  changed();
}
