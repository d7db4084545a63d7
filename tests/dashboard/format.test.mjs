// The dashboard's pure helpers (api/dashboard/format.js), run by `node --test tests/dashboard`.
import assert from "node:assert/strict";
import { test } from "node:test";

import { diff, digitClass, digitMeaning, fmtDelta, fmtGain, fmtLoss, fmtSeconds, isOperator, neuralNames } from "../../api/dashboard/format.js";

test("losses keep four significant digits and switch to exponents outside [1e-3, 1e4)", () => {
  assert.equal(fmtLoss(0.0123456), "0.01235");
  assert.equal(fmtLoss(0.00012346), "1.235e-4");
  assert.equal(fmtLoss(12345), "1.235e+4");
  assert.equal(fmtLoss(0), "0.000");
  for (const missing of [null, undefined, NaN, Infinity]) assert.equal(fmtLoss(missing), "–");
});

test("durations read as a person says them", () => {
  assert.deepEqual([4.25, 42, 185, 7620].map(fmtSeconds), ["4.3 s", "42 s", "3 min 5 s", "2 h 7 min"]);
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
  assert.deepEqual(["0", "1", "2", "7"].map(digitMeaning), ["analytical", "neural module", "choice 2", "choice 7"]);
  assert.deepEqual(["0", "1", "2", "7", "?"].map(digitClass), ["d0", "d1", "d2", "d3", "d0"]);
  assert.ok(isOperator("S*D") && isOperator("M+S*D*F*G*invE") && !isOperator("invE"));
});
