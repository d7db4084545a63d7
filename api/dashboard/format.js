// @ts-check
/* Pure formatting for people: numbers, times, states. No DOM, so `node --test` runs it. */

/** A loss with four significant digits, exponent form outside [1e-3, 1e4); "–" when missing.
 * @param {number | null | undefined} x */
export function fmtLoss(x) {
  if (x === null || x === undefined || !Number.isFinite(x)) return "–";
  if (x !== 0 && (Math.abs(x) < 1e-3 || Math.abs(x) >= 1e4)) return x.toExponential(3);
  return x.toPrecision(4);
}

/** "4.2 s", "42 s", "3 min 5 s", "2 h 7 min".
 * @param {number} s */
export function fmtSeconds(s) {
  if (!Number.isFinite(s)) return "–";
  if (s < 60) return s.toFixed(s < 10 ? 1 : 0) + " s";
  const m = Math.floor(s / 60), r = Math.round(s % 60);
  if (m < 60) return `${m} min ${r} s`;
  return `${Math.floor(m / 60)} h ${m % 60} min`;
}

/** An ISO time in the browser's zone as "YYYY-MM-DD hh:mm:ss"; the input as is when unparseable.
 * @param {string} iso */
export function fmtTime(iso) {
  const d = new Date(iso);
  if (Number.isNaN(d.getTime())) return String(iso);
  const pad = (/** @type {number} */ n) => String(n).padStart(2, "0");
  return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())} ${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}`;
}

/** The served gain over the starting state (a share of its loss removed) as "−38.5% loss".
 * @param {number | null | undefined} gain */
export function fmtGain(gain) {
  if (gain === null || gain === undefined || !Number.isFinite(gain)) return "–";
  return (gain >= 0 ? "−" : "+") + Math.abs(100 * gain).toFixed(1) + "% loss";
}

/** A relative change from `before` to `after` as " −12.0%" / " +3.1%"; null without a positive before.
 * @param {number | null} before @param {number} after */
export function fmtDelta(before, after) {
  if (before === null || !(before > 0)) return null;
  const rel = (after - before) / before;
  return { down: rel <= 0, text: ` ${rel <= 0 ? "−" : "+"}${Math.abs(100 * rel).toFixed(1)}%` };
}

/** @param {string} name a position name: operators carry "*" or "+" */
export function isOperator(name) { return /[*+]/.test(name); }

/** Indices where two state strings differ.
 * @param {string} a @param {string} b @returns {number[]} */
export function diff(a, b) {
  const out = [];
  for (let i = 0; i < Math.max(a.length, b.length); i++) if (a[i] !== b[i]) out.push(i);
  return out;
}

/** The names of the positions a state makes neural (any digit but 0).
 * @param {string} state @param {string[]} positions */
export function neuralNames(state, positions) {
  const out = [];
  for (let i = 0; i < state.length; i++) if (state[i] !== "0") out.push(positions[i] || "#" + i);
  return out;
}

/** What a digit means at a position.
 * @param {string} digit */
export function digitMeaning(digit) {
  return digit === "0" ? "analytical" : digit === "1" ? "neural module" : "choice " + digit;
}

/** The CSS class of a digit's colour: d0, d1, d2, d3 (3 for every higher choice).
 * @param {string} digit */
export function digitClass(digit) {
  return `d${Math.min(Number(digit) || 0, 3)}`;
}
