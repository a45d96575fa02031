// The review page's state: one object every module reads and writes (see review.js for
// what each part holds), and the one notification of its changes. `edit` is the immutable
// editing state ({mask, keypoints, manual, session, outline, maskEdited, kpEdited}); undo and
// redo move between them. A module that changes the state calls `changed` with what it
// changed; the page's entry subscribes the views (panel.js) once, so no module imports the
// functions that draw.

export const S = {
  frame: null,
  proposal: null, // the proposal shown: {id, mask, keypoints, scores, source, source_key, model_id, chosen}
  proposals: [], // every proposal of the frame, newest first (GET /proposals items)
  policyReason: "",
  revision: 0,
  labelStatus: null,
  loadedLabel: null, // { mask, revision } of the label as loaded: clicks on it name it, not send it
  review: null, // the review stage: { state, comment, by } of the label, or null
  overlap: null, // the frame's labels by several annotators (GET /frames/{id}/overlap), or null
  overlapMine: false, // an annotator given this frame among several: saves go to her own label
  stage: null,
  ruler: null, // measuring the run's scale: two ends of a known length
  overlay: null,
  edit: null,
  labelClean: null,
  manualClean: null,
  manualRevision: 0, // the revision of the keypoints placed by hand as loaded or saved (0: none)
  past: [],
  future: [],
  retired: { objects: new Map(), tags: [], attributes: [] }, // the label's retired parts: object uid → position, names (layers.js)
  layer: "pool", // the edited layer: "pool" or an object's uid (layers.js)
  selectedPoint: null, // the named point selected on a points layer
  tool: "positive",
  toolBeforeValidation: "positive",
  maskBeforeValidation: true,
  validation: false,
  leaving: false,
  spaceHeld: false,
  gesture: null,
  inflight: new Set(),
  pngCache: new WeakMap(),
};

// --- the one state-change notification ------------------------------------------------------

/** What a change may touch: "edit" (the editing state: canvas, keypoint list, verdict), "frame"
 *  (the frame, its status and revision), "proposals", "review" (the review stage), "propagate", "layers" (which layer is edited, how each is shown). */
export const PARTS = new Set(["edit", "frame", "proposals", "review", "propagate", "layers"]);
const views = [];

/** Call `view(parts)` after every change of the state, with the set of parts changed. */
export function subscribe(view) {
  views.push(view);
}

/** Say that `parts` of the state changed (the editing state when none is named). */
export function changed(...parts) {
  const what = new Set(parts.length ? parts : ["edit"]);
  for (const part of what) if (!PARTS.has(part)) throw new Error(`No part of the review state is called ${part}.`);
  for (const view of views) view(what);
}
