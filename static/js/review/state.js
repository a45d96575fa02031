// The review page's state: one object every module reads and writes (see review.js for
// what each part holds). `edit` is the immutable editing state ({mask, keypoints, manual,
// session, outline, maskEdited, kpEdited}); undo and redo move between them.

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
