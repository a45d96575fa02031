// The conflict dialog: a save met 409, someone saved the frame's label first. It says who and
// when, shows their pool beside mine, names every class (and the frame's tags and attributes)
// where theirs and mine differ, and lets me keep mine (every class resent) or take theirs (every
// class loaded). What happens then is the caller's: `overwrite(revision)` and `take(label, mask)`.

import { api } from "../api.js";
import { formatDate } from "../ui.js";
import { isProposal } from "./history.js";
import { POOL, objectsFromLabel } from "./layers.js";
import { Mask, MaskOverlay } from "./mask.js";
import { $, FRAME_ID } from "./page.js";
import { S } from "./state.js";

/** Show the dialog for a save of `kind` refused by `error` (409). */
export async function showConflict(kind, error, { overwrite, take }) {
  const current = error.body?.revision ?? 0;
  const by = error.body?.updated_by ?? "someone else";
  $("conflict-text").textContent = `${by} saved this frame's label while you were working on it (it is now at revision ${current}). Take theirs (your changes are dropped; Undo brings them back), or overwrite it with yours — every class, tags and attributes.`;
  const dialog = $("conflict");
  let theirs = null, theirMask = null;
  $("conflict-overwrite").onclick = () => { dialog.close(); overwrite(current); };
  $("conflict-reload").onclick = () => {
    dialog.close();
    if (theirs) take(theirs, theirMask);
    else { S.leaving = true; location.reload(); } // not loaded yet: the page loads it
  };
  $("conflict-cancel").onclick = () => dialog.close();
  const mine = kind === "reject" ? null : S.edit.mask;
  drawPreview($("conflict-mine"), mine, "#00e6ff");
  $("conflict-mine-text").textContent = kind === "reject" ? "Yours: rejected (no pool)" : `Yours: ${kind === "accept" && isProposal() ? "accepted" : "corrected"} · ${mine.area()} px`;
  $("conflict-mine-others").textContent = othersText(S.edit.objects, S.edit.tags);
  $("conflict-theirs-others").textContent = "";
  $("conflict-theirs-text").textContent = "Theirs: loading…";
  $("conflict-classes").textContent = "Comparing every class…";
  delete $("conflict-classes").dataset.classes; // the last conflict's
  dialog.showModal();
  try {
    theirs = await api(`/frames/${FRAME_ID}/label`);
    theirMask = theirs.mask_png ? await Mask.fromPng(theirs.mask_png, S.frame.width, S.frame.height) : null;
    drawPreview($("conflict-theirs"), theirMask, "#ff922b");
    let differs = "";
    if (theirMask && mine) differs = ` · differs from yours in ${pixelsApart(theirMask, mine)} px`;
    $("conflict-theirs-text").textContent = `Theirs: ${theirs.status} by ${theirs.updated_by ?? "?"}, ${formatDate(theirs.updated_at)}${theirMask ? ` · ${theirMask.area()} px` : ""}${differs}`;
    $("conflict-theirs-others").textContent = othersText(objectsFromLabel(theirs, S.frame.width, S.frame.height), theirs.tags ?? []);
    const apart = differing(kind, mine, theirs, theirMask);
    const box = $("conflict-classes");
    box.dataset.classes = JSON.stringify(apart);
    box.textContent = apart.length ? `Theirs and yours differ in: ${apart.join(", ")}.` : "Theirs and yours hold the same classes, tags and attributes.";
  } catch (problem) {
    $("conflict-theirs-text").textContent = `Theirs could not be loaded: ${problem.message}`;
  }
}

/** "wire, 2 spatter · tags humping": what a label holds beside the pool. */
function othersText(objects, tags) {
  const counts = new Map();
  for (const o of objects) counts.set(o.cls, (counts.get(o.cls) ?? 0) + 1);
  const classes = [...counts].map(([name, n]) => (n > 1 ? `${n} ${name}` : name)).join(", ");
  return [classes, tags.length ? `tags ${tags.join(", ")}` : ""].filter(Boolean).join(" · ") || "no other class, no tag";
}

function pixelsApart(a, b) {
  let n = 0;
  for (let i = 0; i < a.data.length; i++) n += a.data[i] !== b.data[i];
  return n;
}

/** One class's objects as comparable parts: how many, their points and attributes as text,
 *  and their union mask (null: none). */
function classParts(objects) {
  const points = objects.filter((o) => o.points).map((o) => Object.entries(o.points).sort().map(([k, [x, y]]) => `${k}:${x.toFixed(1)},${y.toFixed(1)}`).join(";"));
  const attributes = objects.map((o) => JSON.stringify(Object.entries(o.attributes ?? {}).sort()));
  let union = null;
  for (const o of objects.filter((item) => item.mask)) {
    union ??= new Uint8Array(o.mask.data.length);
    for (let i = 0; i < union.length; i++) union[i] |= o.mask.data[i];
  }
  return { text: JSON.stringify([objects.length, points.sort(), attributes.sort()]), union };
}

function sameClass(a, b) {
  const one = classParts(a), other = classParts(b);
  if (one.text !== other.text || (one.union === null) !== (other.union === null)) return false;
  return one.union === null || one.union.every((v, i) => v === other.union[i]);
}

const sameValues = (a, b) => JSON.stringify(Object.entries(a ?? {}).sort()) === JSON.stringify(Object.entries(b ?? {}).sort());

/** The names of what differs between mine (the editing state, saved as `kind`) and their label:
 *  the pool, each other class, "tags", "attributes". */
export function differing(kind, mine, theirs, theirMask) {
  const apart = [];
  const poolMine = kind === "reject" ? null : mine;
  if ((poolMine === null) !== (theirMask === null) || (poolMine && theirMask && pixelsApart(poolMine, theirMask))) apart.push(POOL);
  const theirObjects = objectsFromLabel(theirs, S.frame.width, S.frame.height);
  const names = [...new Set([...S.edit.objects, ...theirObjects].map((o) => o.cls))].sort();
  for (const name of names) {
    const a = S.edit.objects.filter((o) => o.cls === name && (o.points ? Object.keys(o.points).length : o.mask.any()));
    const b = theirObjects.filter((o) => o.cls === name);
    if (!sameClass(a, b)) apart.push(name);
  }
  if ([...S.edit.tags].sort().join("\n") !== [...(theirs.tags ?? [])].sort().join("\n")) apart.push("tags");
  if (!sameValues(S.edit.attributes, theirs.attributes)) apart.push("attributes");
  return apart;
}

/** The frame with a mask's outline and a light fill, scaled into a small canvas. */
export function drawPreview(canvas, mask, colour) {
  const scale = Math.min(canvas.width / S.frame.width, canvas.height / S.frame.height);
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.drawImage(S.stage.image, 0, 0, S.frame.width * scale, S.frame.height * scale);
  if (!mask) return;
  const layer = new MaskOverlay(S.frame.width, S.frame.height);
  layer.paint(mask);
  ctx.globalAlpha = 0.9;
  ctx.drawImage(layer.canvas, 0, 0, S.frame.width * scale, S.frame.height * scale);
  ctx.globalAlpha = 1;
  ctx.strokeStyle = colour;
  ctx.lineWidth = 3;
  ctx.strokeRect(1.5, 1.5, S.frame.width * scale - 3, S.frame.height * scale - 3);
}
