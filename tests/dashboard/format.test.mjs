// The dashboard's pure helpers (api/dashboard/format.js), run by `node --test tests/dashboard`.
import assert from "node:assert/strict";
import { test } from "node:test";

import {
  diff, digitClass, digitMeaning, fmtBudget, fmtCount, fmtDelta, fmtGain, fmtLoss, fmtRunning, fmtSeconds, fmtSlots, fmtStatus,
  isOperator, neuralNames,
} from "../../api/dashboard/format.js";

test("losses keep four significant digits and switch to exponents outside [1e-3, 1e4)", () => {
  assert.equal(fmtLoss(0.0123456), "0.01235");
  assert.equal(fmtLoss(0.00012346), "1.235e-4");
  assert.equal(fmtLoss(12345), "1.235e+4");
  assert.equal(fmtLoss(0), "0.000");
  for (const missing of [null, undefined, NaN, Infinity]) assert.equal(fmtLoss(missing), "–");
});

test("durations read as a person says them", () => {
  assert.deepEqual([4.25, 42, 185, 7620].map(fmtSeconds), ["4.3 s", "42 s", "3 min 5 s", "2 h 7 min"]);
  assert.deepEqual([60, 3600, 7200].map(fmtSeconds), ["1 min", "1 h", "2 h"]);  // no "0 s" tail
  assert.equal(fmtSeconds(NaN), "–");
});

test("a gain is the share of the starting loss removed; a loss that grew reads +", () => {
  assert.equal(fmtGain(0.385), "−38.5% loss");
  assert.equal(fmtGain(-0.02), "+2.0% loss");
  assert.equal(fmtGain(null), "–");
});

test("a round's delta is relative to the previous winner, and absent for the first", () => {
  assert.deepEqual(fmtDelta(2, 1.5), { down: true, text: " −25.0%" });
  assert.deepEqual(fmtDelta(2, 2.2), { down: false, text: " +10.0%" });
  assert.equal(fmtDelta(null, 1), null);
  assert.equal(fmtDelta(0, 1), null);
});

test("states: the positions that differ, the neural ones, what a digit means", () => {
  assert.deepEqual(diff("00011100100", "00011100100"), []);
  assert.deepEqual(diff("00011100100", "10011000100"), [0, 5]);
  assert.deepEqual(diff("01", "012"), [2]);  // a longer state differs where the shorter ends
  assert.deepEqual(neuralNames("0102", ["M", "S", "D", "F"]), ["S", "F"]);
  assert.deepEqual(["0", "1", "2", "7"].map((d) => digitMeaning(d)), ["analytical", "neural module", "choice 2", "choice 7"]);
  const d = ["ggx", "mlp16-32-16", "beckmann"];
  assert.deepEqual(["0", "1", "2"].map((x) => digitMeaning(x, d)), ["ggx (original)", "mlp16-32-16", "beckmann"]);
  // binary states keep their words: one module is "neural module"
  assert.equal(digitMeaning("1", ["schlick", "mlp16-32-16"]), "neural module");
  assert.deepEqual(["0", "1", "2", "7", "?"].map(digitClass), ["d0", "d1", "d2", "d3", "d0"]);
  assert.ok(isOperator("S*D") && isOperator("M+S*D*F*G*invE") && !isOperator("invE"));
});

test("a status carries the reason a job ended there, as the CLI prints it", () => {
  assert.equal(fmtStatus("STOPPED", "budget"), "STOPPED (budget)");
  assert.equal(fmtStatus("STOPPED", null), "STOPPED");
  assert.equal(fmtStatus("RUNNING", undefined), "RUNNING");
});

test("a budget reads as used of allowed, one part per limit set", () => {
  assert.deepEqual(fmtBudget({ wall_s: 60, cpu_s: null }, 12.3, 40), ["wall 12 s of 1 min"]);
  assert.deepEqual(fmtBudget({ wall_s: 60, cpu_s: 600 }, 4.25, 185), ["wall 4.3 s of 1 min", "CPU 3 min 5 s of 10 min"]);
  assert.deepEqual(fmtBudget({ wall_s: null, cpu_s: null }, 1, 1), []);
  assert.deepEqual(fmtBudget(undefined, 1, 1), []);
});

test("slots held: counts with their units, GPUs only when held", () => {
  assert.deepEqual([[1, "CPU"], [3, "CPU"], [0, "GPU"], [0.5, "GPU"], [1.5, "CPU"], [2 / 3, "GPU"]].map(([n, u]) => fmtCount(n, u)),
    ["1 CPU", "3 CPUs", "0 GPUs", "0.5 GPU", "1.5 CPUs", "0.67 GPU"]);
  assert.equal(fmtSlots({ candidates: 3, cpus: 3, gpus: 0 }), "3 candidates · 3 CPUs");
  assert.equal(fmtSlots({ candidates: 1, cpus: 2, gpus: 0.25 }), "1 candidate · 2 CPUs · 0.25 GPU");
  assert.equal(fmtSlots({ candidates: 0, cpus: 0, gpus: 0 }), "no candidate in flight");
  assert.equal(fmtSlots(undefined), "no candidate in flight");
});

test("the running jobs against the service's limit", () => {
  assert.equal(fmtRunning(2, 4), "2 of at most 4 running");
  assert.equal(fmtRunning(1, null), "1 running");
});
