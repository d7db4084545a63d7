// The chart's axis arithmetic (api/dashboard/scale.js), run by `node --test tests/dashboard`.
import assert from "node:assert/strict";
import { test } from "node:test";

import { fmtTick, logTicks, lossAxis, niceLinearTicks } from "../../api/dashboard/scale.js";

test("linear ticks are round multiples of 1, 2, 2.5 or 5 × 10^k inside the range", () => {
  for (const [lo, hi] of [[0, 1], [0.0123, 0.0456], [-3, 17], [1e5, 1.7e5], [0.5, 0.5]]) {
    const ticks = niceLinearTicks(lo, hi, 6);
    assert.ok(ticks.length >= 1 && ticks.length <= 7, `${lo}..${hi}: ${ticks}`);
    for (const t of ticks) assert.ok(t >= lo - 1e-12 && t <= hi + 1e-9 * Math.abs(hi || 1), `${t} outside ${lo}..${hi}`);
    if (ticks.length > 1) {
      const step = ticks[1] - ticks[0];
      const mantissa = step / Math.pow(10, Math.floor(Math.log10(step)));
      assert.ok([1, 2, 2.5, 5].some((m) => Math.abs(mantissa - m) < 1e-9), `step ${step}`);
    }
  }
  assert.deepEqual(niceLinearTicks(0, 1, 5), [0, 0.2, 0.4, 0.6, 0.8, 1]);
});

test("tick labels carry just the decimals their spacing needs", () => {
  assert.equal(fmtTick(0.25, 0.05), "0.25");
  assert.equal(fmtTick(3, 1), "3");
  assert.equal(fmtTick(0.0002, 0.0001), "2.0e-4");
});

test("log ticks are 1, 2, 5 × 10^k; fewer than two is null", () => {
  assert.deepEqual(logTicks(0.009, 0.21), [0.01, 0.02, 0.05, 0.1, 0.2]);
  assert.equal(logTicks(3, 4), null);
});

test("the loss axis turns log beyond a factor 4 and maps lower losses lower on the page", () => {
  for (const [losses, log] of [[[0.01, 0.02, 0.03], false], [[0.01, 1.5], true]]) {
    const axis = lossAxis(losses, 30, 260);
    assert.equal(axis.log, log);
    const ys = losses.map(axis.y);
    for (let i = 1; i < ys.length; i++) assert.ok(ys[i] < ys[i - 1], "a higher loss is drawn higher");
    for (const y of ys) assert.ok(y > 30 && y < 260, "the data sit inside the plot, with a margin");
  }
  const empty = lossAxis([], 0, 100);
  assert.ok(Number.isFinite(empty.y(0.5)) && empty.ticks.length > 0);
});
