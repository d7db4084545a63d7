"""A committed round as the API shows it: typed fields of the store that older clients read from
``extra`` still appear there."""

from neuenh_service.api.schemas import Naming, RoundPublic
from neuenh_service.storage import CandidateRecord, RoundRecord

BASE = {"data": [{"source": "synthetic_zoo", "materials": 2, "samples": 10}]}
STAY, FLIP = "00000000000", "00001000000"


def test_the_stop_reason_reads_as_extra_stop_when_as_before_it_was_a_column():
    candidates = (CandidateRecord(STAY, 0.5, 0.4, 3, 1.0), CandidateRecord(FLIP, 0.5, 0.3, 3, 1.0))
    stopped = RoundRecord(0, STAY, FLIP, candidates, 1.0, 2.0, extra={"radius": 1}, stop_reason="gain 0.5 % < 1 %")
    public = RoundPublic.from_record(stopped, Naming.of(BASE), start=0.4).model_dump(mode="json")
    assert public["extra"] == {"radius": 1, "stop_when": "gain 0.5 % < 1 %"}
    going_on = RoundRecord(0, STAY, FLIP, candidates, 1.0, 2.0, extra={"radius": 1})
    assert RoundPublic.from_record(going_on, Naming.of(BASE), start=0.4).model_dump(mode="json")["extra"] == {"radius": 1}
