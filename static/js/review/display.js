// What the reviewer sets up stays from frame to frame (this browser): display controls,
// brush and tool, the mask and heatmap overlays.

import { toast } from "../ui.js";
import { $, FRAME_ID } from "./page.js";
import { S } from "./state.js";

// --- what the reviewer set up stays from frame to frame (this browser) -------------------------

export const PREFS_KEY = "weldpool.review";
export const prefs = () => { try { return JSON.parse(localStorage.getItem(PREFS_KEY)) ?? {}; } catch { return {}; } };
export function remember(values) {
  localStorage.setItem(PREFS_KEY, JSON.stringify({ ...prefs(), ...values }));
}

export const DISPLAY = { brightness: "display-brightness", contrast: "display-contrast", gamma: "display-gamma", maskOpacity: "display-opacity" };
export const DEFAULT_DISPLAY = { brightness: 1, contrast: 1, gamma: 1, maskOpacity: 1, keypoints: true, outlineOnly: false };

export function applyDisplay(values) {
  S.stage.display = { ...DEFAULT_DISPLAY, ...values };
  for (const [key, id] of Object.entries(DISPLAY)) {
    $(id).value = String(S.stage.display[key]);
    $(`${id}-value`).textContent = Number(S.stage.display[key]).toFixed(2);
  }
  $("display-keypoints").checked = S.stage.display.keypoints;
  $("display-outline").checked = S.stage.display.outlineOnly;
  fillMask();
  for (const channel of document.querySelectorAll("#gamma-filter feComponentTransfer > *")) {
    channel.setAttribute("exponent", String(1 / S.stage.display.gamma)); // gamma > 1 brightens the mid-tones
  }
  S.stage.canvas.dataset.display = JSON.stringify(S.stage.display);
  remember({ display: S.stage.display });
  S.stage.requestRender();
}

export function bindDisplay() {
  for (const [key, id] of Object.entries(DISPLAY)) {
    $(id).addEventListener("input", (event) => applyDisplay({ ...S.stage.display, [key]: Number(event.target.value) }));
  }
  $("display-keypoints").addEventListener("change", (event) => applyDisplay({ ...S.stage.display, keypoints: event.target.checked }));
  $("display-outline").addEventListener("change", (event) => applyDisplay({ ...S.stage.display, outlineOnly: event.target.checked }));
  $("display-reset").addEventListener("click", () => applyDisplay(DEFAULT_DISPLAY));
  applyDisplay(prefs().display ?? DEFAULT_DISPLAY);
}

export function setMaskVisible(on) {
  $("show-mask").checked = on;
  S.stage.showMask = on;
  S.stage.requestRender();
}

export async function setHeatmapVisible(on) {
  $("show-heatmap").checked = on;
  S.stage.showHeatmap = on;
  fillMask();
  if (on && !S.stage.heatmap && S.proposal) {
    const image = new Image();
    image.src = `/api/v1/frames/${FRAME_ID}/proposal/heatmap.png?proposal_id=${S.proposal.id}`;
    try { await image.decode(); S.stage.heatmap = image; S.stage.canvas.dataset.heatmap = "loaded"; } catch { toast("The heatmap could not be loaded.", "error"); }
  }
  S.stage.requestRender();
}

/** The mask is drawn as its outline only when asked, and always over the heatmap (readable). */
export function fillMask() {
  S.overlay.setFilled(!S.stage.display.outlineOnly && !S.stage.showHeatmap);
  S.stage.canvas.dataset.maskFill = String(S.overlay.filled);
  S.stage.requestRender();
}
