// Inline SVG line charts (no library): one small chart per quantity, epochs on the x axis.

const NS = "http://www.w3.org/2000/svg";

function svg(tag, attrs = {}, text) {
  const node = document.createElementNS(NS, tag);
  for (const [key, value] of Object.entries(attrs)) node.setAttribute(key, String(value));
  if (text !== undefined) node.textContent = text;
  return node;
}

/** Round, readable tick values covering [low, high]. */
export function ticks(low, high, count = 4) {
  if (!(high > low)) return [low];
  const raw = (high - low) / count;
  const step = [1, 2, 2.5, 5, 10].map((m) => m * 10 ** Math.floor(Math.log10(raw))).find((s) => s >= raw);
  const out = [];
  for (let v = Math.ceil(low / step) * step; v <= high + step * 1e-9; v += step) out.push(Number(v.toPrecision(12)));
  return out;
}

const CHAR_PX = 6.2; // the width of a tick label's character (10 px system-ui), at most

/** [low, high] widened about its middle to at least ``span`` (never below 0 for values that
 * are not). */
export function spanAtLeast(low, high, span) {
  if (!(span > high - low)) return [low, high];
  const middle = (low + high) / 2;
  if (low >= 0 && middle < span / 2) return [0, span];
  return [middle - span / 2, middle + span / 2];
}

/** The least y span of a pool quantity's chart (timeline, live view): by unit, and a tenth of
 * its mean; a steady pool reads as a flat line, not as its noise (0.0005 mm) zoomed to fill the
 * chart. */
const LEAST_SPAN = { mm: 0.5, "mm²": 1, px: 5, "px²": 100 };
export function leastSpan(values, unit) {
  const finite = values.filter(Number.isFinite);
  const mean = finite.length ? finite.reduce((a, b) => a + b, 0) / finite.length : 0;
  return Math.max(LEAST_SPAN[unit] ?? 0, 0.1 * Math.abs(mean));
}

/** A tick's label, with as many decimals as the step between ticks needs: ticks 0.0005 apart
 *  never read "0.981, 0.981, 0.981". */
export function format(value, step = 0) {
  if (value === 0) return "0";
  const abs = Math.abs(value);
  if (abs !== 0 && (abs < 0.01 || abs >= 1e4) && !(step > 0 && abs >= 0.01)) {
    const digits = step > 0 ? Math.max(1, Math.ceil(Math.log10(abs / step))) : 1;
    return value.toExponential(Math.min(6, digits));
  }
  if (step > 0) {
    let decimals = 0; // the fewest that write the step exactly (0.25 needs 2, 0.0005 needs 4)
    while (decimals < 8 && Math.abs(Math.round(step * 10 ** decimals) - step * 10 ** decimals) > 1e-6) decimals += 1;
    return value.toFixed(decimals);
  }
  return String(Number(value.toPrecision(3)));
}

/**
 * A line chart of `series` ([{name, colour, points: [[x, y], …], dots?}]) as an <svg> element;
 * a series with `dots` is drawn as markers only.
 * `domain` fixes the y range (e.g. [0, 1] for mIoU); otherwise it fits the data, over at least
 * `minSpan` (a physical quantity: a steady pool's width must look steady, not its noise zoomed
 * to fill the chart); `xDomain` fixes the x range (charts of one run side by side). The margins
 * fit the tick labels, so none is cut off.
 */
export function lineChart({ title, series, width = 300, height = 160, domain = null, xDomain = null, minSpan = 0, unit = "", xLabel = "epoch", onPick = null }) {
  const pad = { left: 44, right: 12, top: 22, bottom: 26 };
  const all = series.flatMap((s) => s.points).filter(([x, y]) => Number.isFinite(x) && Number.isFinite(y));
  const root = svg("svg", { viewBox: `0 0 ${width} ${height}`, width, height, class: "chart", role: "img", "aria-label": title });
  root.append(svg("text", { x: pad.left, y: 14, class: "chart-title" }, title + (unit ? ` (${unit})` : "")));
  if (!all.length) {
    root.append(svg("text", { x: width / 2, y: height / 2, class: "chart-empty", "text-anchor": "middle" }, "no data"));
    return root;
  }
  const xs = all.map(([x]) => x);
  const ys = all.map(([, y]) => y);
  const [xLow, xHigh] = xDomain ?? [Math.min(...xs), Math.max(...xs)]; // xDomain: shared with other charts
  const [x0, x1] = [xLow, xHigh === xLow ? xLow + 1 : xHigh];
  let [y0, y1] = domain ?? spanAtLeast(Math.min(...ys), Math.max(...ys), minSpan);
  if (y1 - y0 < 1e-12) { y0 -= 0.5 * (Math.abs(y0) || 1); y1 += 0.5 * (Math.abs(y1) || 1); }
  const yTicks = ticks(y0, y1);
  const yStep = yTicks.length > 1 ? yTicks[1] - yTicks[0] : 0;
  const xTicks = ticks(x0, x1, Math.min(5, Math.max(1, x1 - x0))).filter(Number.isInteger);
  // room for the longest y label left of the axis, and half the last x label right of it
  pad.left = Math.max(pad.left, 10 + CHAR_PX * Math.max(...yTicks.map((t) => format(t, yStep).length)));
  pad.right = Math.max(pad.right, 4 + (CHAR_PX * format(xTicks.at(-1) ?? 0).length) / 2);
  root.dataset.yDomain = `${y0} ${y1}`;
  const sx = (x) => pad.left + ((x - x0) / (x1 - x0)) * (width - pad.left - pad.right);
  const sy = (y) => height - pad.bottom - ((y - y0) / (y1 - y0)) * (height - pad.top - pad.bottom);
  const grid = svg("g", { class: "grid" });
  for (const t of yTicks) {
    grid.append(svg("line", { x1: pad.left, x2: width - pad.right, y1: sy(t), y2: sy(t) }));
    grid.append(svg("text", { x: pad.left - 6, y: sy(t) + 4, "text-anchor": "end", class: "y-tick" }, format(t, yStep)));
  }
  // x counts epochs or labels: whole numbers only, never "1.2 epochs".
  for (const t of xTicks) {
    grid.append(svg("text", { x: sx(t), y: height - pad.bottom + 16, "text-anchor": "middle" }, format(t)));
  }
  grid.append(svg("text", { x: 4, y: height - pad.bottom + 16, class: "axis-label" }, xLabel));
  root.append(grid);
  for (const s of series) {
    const points = s.points.filter(([x, y]) => Number.isFinite(x) && Number.isFinite(y));
    if (!points.length) continue;
    if (s.dots) { // separate observations (e.g. reviewed frames): markers, no line between them
      for (const [x, y] of points) root.append(svg("circle", { cx: sx(x), cy: sy(y), r: 3.5, fill: s.colour, "data-series": s.name }));
      continue;
    }
    const d = points.map(([x, y], i) => `${i ? "L" : "M"}${sx(x).toFixed(1)},${sy(y).toFixed(1)}`).join("");
    root.append(svg("path", { d, class: "line", stroke: s.colour, "data-series": s.name }));
    const [lx, ly] = points[points.length - 1];
    root.append(svg("circle", { cx: sx(lx), cy: sy(ly), r: 3, fill: s.colour }));
  }
  if (onPick) { // a click picks the nearest x (a frame of a run)
    root.classList.add("pickable");
    root.addEventListener("click", (event) => {
      const box = root.getBoundingClientRect();
      const vx = ((event.clientX - box.left) / box.width) * width;
      onPick(x0 + ((vx - pad.left) / (width - pad.left - pad.right)) * (x1 - x0));
    });
  }
  if (series.length > 1) {
    let x = width - pad.right;
    for (const s of [...series].reverse()) {
      const label = svg("text", { x, y: 14, "text-anchor": "end", fill: s.colour, class: "legend" }, s.name);
      root.append(label);
      x -= s.name.length * 6.5 + 12;
    }
  }
  return root;
}
