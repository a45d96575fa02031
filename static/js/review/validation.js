// The validation mode: keypoints placed by hand (Algorithm 1's k of them), saved apart from
// the label with their own revision check.

import { ApiError, api } from "../api.js";
import { formatDate, toast } from "../ui.js";
import { setMaskVisible } from "./display.js";
import { commit } from "./history.js";
import { $, FRAME_ID } from "./page.js";
import { S, changed } from "./state.js";
import { enableTools, setTool } from "./tools.js";

/** Save the keypoints placed by hand from the revision they were read at; when someone else
 *  saved theirs meanwhile (409), the user chooses: overwrite theirs, or load theirs. */
export async function saveValidation() {
  const put = (base) => api(`/frames/${FRAME_ID}/validation-keypoints`, { method: "PUT", json: { keypoints: S.edit.manual, base_revision: base } });
  try {
    let saved;
    try {
      saved = await put(S.manualRevision);
    } catch (error) {
      if (!(error instanceof ApiError && error.status === 409)) throw error;
      const current = error.body?.revision ?? 0;
      const who = error.body?.updated_by ?? "Someone else";
      if (!confirm(`${who} saved this frame's validation keypoints while you placed yours.\n\nOK: overwrite theirs with yours. Cancel: load theirs.`)) {
        const theirs = await api(`/frames/${FRAME_ID}/validation-keypoints`);
        S.manualRevision = theirs.revision;
        commit({ ...S.edit, manual: theirs.keypoints.map((p) => [...p]) });
        S.manualClean = S.edit.manual;
        $("validation-state").textContent = `${theirs.keypoints.length} keypoints placed by hand (${formatDate(theirs.updated_at)}), loaded.`;
        changed();
        return;
      }
      saved = await put(current);
    }
    S.manualRevision = saved.revision;
    S.manualClean = S.edit.manual;
    S.frame.split = "validation";
    changed("frame");
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
