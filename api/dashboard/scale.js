// @ts-check
/* Axis ticks for the chart. Pure, so `node --test` runs it. */

/** About `count` round ticks (1, 2, 2.5, 5 × a power of ten) covering [lo, hi].
 * @param {number} lo @param {number} hi @param {number} count @returns {number[]} */
export function niceLinearTicks(lo, hi, count) {
  const span = hi - lo || Math.abs(hi) || 1;
  const raw = span / Math.max(count, 1);
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((s) => span / s <= count) || 10 * mag;
  const ticks = [];
  for (let t = Math.ceil(lo / step) * step; t <= hi + step * 1e-9; t += step) ticks.push(Number(t.toPrecision(12)));
  return ticks;
}

/** A tick label with just the decimals its spacing needs.
 * @param {number} t @param {number} step */
export function fmtTick(t, step) {
  if (t !== 0 && (Math.abs(t) < 1e-3 || Math.abs(t) >= 1e4)) return t.toExponential(1);
  const decimals = Math.max(0, Math.min(8, -Math.floor(Math.log10(step || Math.abs(t) || 1) + 1e-9)));
  return t.toFixed(decimals);
}

/** 1, 2, 5 × powers of ten inside [lo, hi] (lo > 0); null when fewer than two fit.
 * @param {number} lo @param {number} hi @returns {number[] | null} */
export function logTicks(lo, hi) {
  const ticks = [];
  for (let e = Math.floor(Math.log10(lo)); e <= Math.ceil(Math.log10(hi)); e++) {
    for (const m of [1, 2, 5]) {
      const t = m * Math.pow(10, e);
      if (t >= lo && t <= hi) ticks.push(t);
    }
  }
  return ticks.length >= 2 ? ticks : null;
}

/**
 * The chart's y axis over the losses: log when they span more than a factor 4, else linear with
 * round ticks; a margin of 5 % (log) or 8 % (linear) beyond the data.
 * @param {number[]} losses finite values
 * @param {number} top pixel y of the plot's top @param {number} bottom pixel y of its bottom
 * @returns {{log: boolean, y: (v: number) => number, ticks: number[], label: (t: number) => string}}
 */
export function lossAxis(losses, top, bottom) {
  let lo = losses.length ? Math.min(...losses) : 0.1;
  let hi = losses.length ? Math.max(...losses) : 1;
  const height = bottom - top;
  if (lo > 0 && hi / lo > 4) {
    const a = Math.log10(lo) - 0.05 * (Math.log10(hi) - Math.log10(lo));
    const b = Math.log10(hi) + 0.05 * (Math.log10(hi) - Math.log10(lo));
    return {
      log: true,
      y: (v) => top + height * (1 - (Math.log10(v) - a) / (b - a)),
      ticks: logTicks(Math.pow(10, a), Math.pow(10, b)) || [Math.pow(10, a), Math.pow(10, b)],
      label: (t) => fmtTick(t, t),
    };
  }
  const pad = (hi - lo) * 0.08 || Math.abs(hi) * 0.05 || 0.01;
  lo -= pad; hi += pad;
  const ticks = niceLinearTicks(lo, hi, 6);
  return {
    log: false,
    y: (v) => top + height * (1 - (v - lo) / (hi - lo)),
    ticks,
    label: (t) => fmtTick(t, ticks.length > 1 ? ticks[1] - ticks[0] : t),
  };
}
