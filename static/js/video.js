// How many frames a video file holds, read from its header in the browser before anything is
// uploaded (so the sampling step can be chosen with the count in view). Two fixed header fields
// suffice: MP4/MOV — the video track's sample count (stsz) and duration (mdhd); AVI — the main
// header's frame count and frame time (avih). A library (mp4box.js) would be ~300 KB for these.
// Null when the header cannot be read: the server still probes every video with OpenCV.

const MAX_MOOV = 64 * 1024 * 1024;

const text = (view, at) => String.fromCharCode(view.getUint8(at), view.getUint8(at + 1), view.getUint8(at + 2), view.getUint8(at + 3));

/** {frames, fps, duration_s} of an MP4/MOV or AVI file, or null. */
export async function probeVideo(file) {
  try {
    const head = new DataView(await file.slice(0, 16).arrayBuffer());
    if (head.byteLength >= 12 && text(head, 0) === "RIFF" && text(head, 8) === "AVI ") return await probeAvi(file);
    if (head.byteLength >= 8 && text(head, 4) === "ftyp") return await probeMp4(file);
  } catch { /* an unreadable header: no estimate */ }
  return null;
}

async function probeAvi(file) {
  const view = new DataView(await file.slice(0, 8192).arrayBuffer());
  for (let at = 12; at + 40 <= view.byteLength; at++) {
    if (text(view, at) !== "avih") continue;
    const microseconds = view.getUint32(at + 8, true);
    const frames = view.getUint32(at + 8 + 16, true);
    if (!frames || !microseconds) return null;
    const fps = 1e6 / microseconds;
    return { frames, fps, duration_s: frames / fps };
  }
  return null;
}

/** The boxes of `view` between `start` and `end`: [{type, start (of the payload), end}]. */
function boxes(view, start, end) {
  const found = [];
  for (let at = start; at + 8 <= end;) {
    let size = view.getUint32(at);
    let header = 8;
    if (size === 1) { size = Number(view.getBigUint64(at + 8)); header = 16; }
    if (size === 0) size = end - at;
    if (size < header) break;
    found.push({ type: text(view, at + 4), start: at + header, end: Math.min(end, at + size) });
    at += size;
  }
  return found;
}

const child = (view, box, type) => boxes(view, box.start, box.end).find((b) => b.type === type);

async function probeMp4(file) {
  // Top-level boxes: read their headers only, then the whole moov.
  let moov = null;
  for (let at = 0; at + 8 <= file.size;) {
    const header = new DataView(await file.slice(at, at + 16).arrayBuffer());
    let size = header.getUint32(0);
    if (size === 1) size = Number(header.getBigUint64(8));
    if (size === 0) size = file.size - at;
    if (size < 8) return null;
    if (text(header, 4) === "moov") { moov = { at, size }; break; }
    at += size;
  }
  if (!moov || moov.size > MAX_MOOV) return null;
  const view = new DataView(await file.slice(moov.at, moov.at + moov.size).arrayBuffer());
  const root = boxes(view, 0, view.byteLength)[0];
  for (const trak of boxes(view, root.start, root.end).filter((b) => b.type === "trak")) {
    const mdia = child(view, trak, "mdia");
    const hdlr = mdia && child(view, mdia, "hdlr");
    if (!hdlr || text(view, hdlr.start + 8) !== "vide") continue;
    const mdhd = child(view, mdia, "mdhd");
    if (!mdhd) return null;
    const version = view.getUint8(mdhd.start);
    const timescale = view.getUint32(mdhd.start + (version === 1 ? 20 : 12));
    const duration = version === 1 ? Number(view.getBigUint64(mdhd.start + 24)) : view.getUint32(mdhd.start + 16);
    const minf = child(view, mdia, "minf");
    const stbl = minf && child(view, minf, "stbl");
    const stsz = stbl && (child(view, stbl, "stsz") ?? child(view, stbl, "stz2"));
    if (!stsz || !timescale || !duration) return null;
    const frames = view.getUint32(stsz.start + 8);
    const seconds = duration / timescale;
    return { frames, fps: frames / seconds, duration_s: seconds };
  }
  return null;
}
