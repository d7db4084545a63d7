"""The plain-text pieces both command lines print (``cli/tables.py``)."""

from __future__ import annotations

import pytest

from neuenh_service.cli.tables import STILL_LEARNING_DROP, against_plain, last_quarter_drop, still_learning, table


@pytest.mark.parametrize("enhanced, plain, state, words", [
    (0.03, 0.04, "00000010000", "the enhancement lowers the validation loss by 25.0%"),
    (0.03927, 0.03405, "00000010000", "the enhancement does not lower the validation loss: 15.3% above plain GGX's"),
    (0.05, 0.05, "00000010000", "the enhancement does not lower the validation loss: 0.0% above plain GGX's"),
    (0.03250, 0.03289, "00000000000",
     "the search kept plain GGX: no module paid on this data (1.2% below one run of as many epochs)"),
], ids=["lower", "higher", "equal", "kept-plain"])
def test_the_enhancement_against_plain_says_which_way_it_went(enhanced, plain, state, words):
    assert against_plain(enhanced, plain, state) == words


@pytest.mark.parametrize("losses, drop", [
    ([1 / (e + 1) for e in range(32)], 1 - 24 / 32),  # the last quarter: epochs 24 to 32 of 1/(e + 1)
    ([0.5] * 12, 0.0),
    ([0.5, 0.4, 0.3, 0.45], 1 - 0.45 / 0.3),  # a loss that rose: a negative drop
    ([0.3, 0.2, 0.1], None),  # under four epochs: no quarter to compare
    ([0.3, 0.0, 0.0, 0.0], None),  # nothing to be relative to
], ids=["falling", "flat", "rising", "too-short", "zero"])
def test_the_last_quarter_drop_is_the_relative_fall_over_the_last_quarter_of_the_epochs(losses, drop):
    assert last_quarter_drop(losses) == (None if drop is None else pytest.approx(drop, rel=1e-12))


def test_a_baseline_still_learning_is_said_and_one_that_levelled_off_is_not():
    levelling = [1.0] * 12 + [0.99, 0.98, 0.97, 0.96]  # over the last 4 of 16 epochs: 1 - 0.96 = 4.0 %
    assert still_learning("plain GGX", levelling) == ""
    falling = levelling + [0.94, 0.93, 0.92, 0.91]  # over the last 5 of 20: 1 - 0.91 / 0.97 = 6.2 %
    assert STILL_LEARNING_DROP < 1 - 0.91 / 0.97
    assert still_learning("plain GGX", falling) == (
        "at equal epochs only: plain GGX's training loss still fell 6.2% over its last 5 epochs")


def test_a_table_aligns_its_columns_and_right_aligns_numbers():
    assert table([["name", "loss"], ["steel", "0.5"], ["ab", "10.25"]], right={1}) == (
        "name    loss\nsteel    0.5\nab     10.25")
