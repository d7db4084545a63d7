"""The plain-text pieces both command lines print (``cli/tables.py``)."""

from __future__ import annotations

import pytest

from neuenh_service.cli.tables import against_plain, table


@pytest.mark.parametrize("enhanced, plain, words", [
    (0.03, 0.04, "the enhancement lowers the validation loss by 25.0%"),
    (0.03927, 0.03405, "the enhancement does not lower the validation loss: 15.3% above plain GGX's"),
    (0.05, 0.05, "the enhancement does not lower the validation loss: 0.0% above plain GGX's"),
], ids=["lower", "higher", "equal"])
def test_the_enhancement_against_plain_says_which_way_it_went(enhanced, plain, words):
    assert against_plain(enhanced, plain) == words


def test_a_table_aligns_its_columns_and_right_aligns_numbers():
    assert table([["name", "loss"], ["steel", "0.5"], ["ab", "10.25"]], right={1}) == (
        "name    loss\nsteel    0.5\nab     10.25")
