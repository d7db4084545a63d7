"""The plain-text pieces both command lines print (``cli/tables.py``)."""

from __future__ import annotations

import pytest

from neuenh_service.cli.tables import against_plain, table


@pytest.mark.parametrize("enhanced, plain, state, words", [
    (0.03, 0.04, "00000010000", "the enhancement lowers the validation loss by 25.0%"),
    (0.03927, 0.03405, "00000010000", "the enhancement does not lower the validation loss: 15.3% above plain GGX's"),
    (0.05, 0.05, "00000010000", "the enhancement does not lower the validation loss: 0.0% above plain GGX's"),
    (0.03250, 0.03289, "00000000000",
     "the search kept plain GGX: no module paid on this data (1.2% below one run of as many epochs)"),
], ids=["lower", "higher", "equal", "kept-plain"])
def test_the_enhancement_against_plain_says_which_way_it_went(enhanced, plain, state, words):
    assert against_plain(enhanced, plain, state) == words


def test_a_table_aligns_its_columns_and_right_aligns_numbers():
    assert table([["name", "loss"], ["steel", "0.5"], ["ab", "10.25"]], right={1}) == (
        "name    loss\nsteel    0.5\nab     10.25")
