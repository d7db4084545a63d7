// @ts-check
/* Pure formatting for people: numbers, times, states. No DOM, so `node --test` runs it. */

/** A loss with four significant digits, exponent form outside [1e-3, 1e4); "–" when missing.
 * @param {number | null | undefined} x */
export function fmtLoss(x) {
  if (x === null || x === undefined || !Number.isFinite(x)) return "–";
  if (x !== 0 && (Math.abs(x) < 1e-3 || Math.abs(x) >= 1e4)) return x.toExponential(3);
  return x.toPrecision(4);
}

/** "4.2 s", "42 s", "3 min 5 s", "2 h 7 min" ("1 min", "2 h" when the rest is 0).
 * @param {number} s */
export function fmtSeconds(s) {
  if (!Number.isFinite(s)) return "–";
  if (s < 60) return s.toFixed(s < 10 ? 1 : 0) + " s";
  const m = Math.floor(s / 60), r = Math.round(s % 60);
  if (m < 60) return r ? `${m} min ${r} s` : `${m} min`;
  return m % 60 ? `${Math.floor(m / 60)} h ${m % 60} min` : `${Math.floor(m / 60)} h`;
}

/** A status with the reason a job that did not fail ended there: "STOPPED (budget)".
 * @param {string} status @param {string | null | undefined} reason */
export function fmtStatus(status, reason) {
  return reason ? `${status} (${reason})` : status;
}

/** What a job spent of its budget, one part per limit set: ["wall 12 s of 1 min", "CPU 40 s of 2 min"];
 * empty without a budget.
 * @param {{wall_s?: number | null, cpu_s?: number | null} | null | undefined} budget
 * @param {number} usedWall @param {number} usedCpu @returns {string[]} */
export function fmtBudget(budget, usedWall, usedCpu) {
  const out = [];
  if (budget && budget.wall_s) out.push(`wall ${fmtSeconds(usedWall)} of ${fmtSeconds(budget.wall_s)}`);
  if (budget && budget.cpu_s) out.push(`CPU ${fmtSeconds(usedCpu)} of ${fmtSeconds(budget.cpu_s)}`);
  return out;
}

/** "1 candidate", "3 CPUs", "0.5 GPU": a count with its unit, plural for 0 and above 1.
 * @param {number} n @param {string} unit */
export function fmtCount(n, unit) {
  const text = Number.isInteger(n) ? String(n) : String(Number(n.toFixed(2)));
  return `${text} ${unit}${n > 1 || n === 0 ? "s" : ""}`;
}

/** What a running job's candidates in flight hold: "3 candidates · 3 CPUs" (GPUs when any).
 * @param {{candidates: number, cpus: number, gpus: number} | null | undefined} holder */
export function fmtSlots(holder) {
  if (!holder || !holder.candidates) return "no candidate in flight";
  const parts = [fmtCount(holder.candidates, "candidate"), fmtCount(holder.cpus, "CPU")];
  if (holder.gpus > 0) parts.push(fmtCount(holder.gpus, "GPU"));
  return parts.join(" · ");
}

/** The running jobs against the service's limit: "2 of at most 4 running".
 * @param {number} running @param {number | null | undefined} max */
export function fmtRunning(running, max) {
  return max ? `${running} of at most ${max} running` : `${running} running`;
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

/** What a digit means at a position: its choice's name when the job serves them (e.g. "beckmann",
 * "mlp16-32-16"), else "analytical", "neural module" or "choice N".
 * @param {string} digit @param {string[]} [names] the position's choices by digit */
export function digitMeaning(digit, names) {
  const named = names && names[parseInt(digit, 36)];
  if (named && !(digit === "1" && names.length === 2)) return digit === "0" ? `${named} (original)` : named;
  return digit === "0" ? "analytical" : digit === "1" ? "neural module" : "choice " + digit;
}

/** The CSS class of a digit's colour: d0, d1, d2, d3 (3 for every higher choice).
 * @param {string} digit */
export function digitClass(digit) {
  return `d${Math.min(Number(digit) || 0, 3)}`;
}
