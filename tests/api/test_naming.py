"""How the API names a job's digits: positions, each position's choices, and the changes of a trail."""

from neuenh_service.api.schemas import Naming

BASE = {"data": [{"source": "synthetic_zoo", "materials": 2, "samples": 10}]}


def test_binary_states_read_as_before():
    naming = Naming.of(BASE)
    assert naming.choices["G"] == ("smith", "mlp16-32-16") and naming.names == {}
    assert naming.change("00000000000", "00001000000") == "+G"


def test_alternatives_and_module_sizes_are_named():
    naming = Naming.of({**BASE, "alternatives": True, "module": {"hidden": [16, 32, 16], "alternatives": [[8, 16, 8]]}})
    assert naming.choices["D"] == ("ggx", "mlp16-32-16", "mlp8-16-8", "beckmann", "gtr", "student_t", "hazy_ggx")
    assert naming.change("00000000000", "00300000000") == "+D[beckmann]"
    assert naming.change("00300000000", "00500000000") == "D[beckmann->student_t]"
    assert naming.change("00300000010", "00000000020") == "-D S*D*F*G*invE[mlp16-32-16->mlp8-16-8]"


def test_a_stored_spec_this_version_refuses_still_names_its_positions():
    naming = Naming.of({"model": "ggx", "search": {"no_such_field": 1}, **BASE})
    assert naming.positions[:3] == ("M", "S", "D") and naming.names == {}
