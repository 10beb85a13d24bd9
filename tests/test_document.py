"""solidkit.document.validate_versioned: the kind / format version / conventions / field checks, in that order,
each a one-line error naming the file."""

from __future__ import annotations

import pytest
from pydantic import BaseModel

from solidkit.document import validate_versioned
from solidkit.envmap.coords import CONVENTIONS_VERSION
from solidkit.errors import ConventionsError, InputError


class Doc(BaseModel):
    kind: str
    version: int
    conventions_version: int
    n: int


GOOD = {"kind": "solidkit-doc", "version": 2, "conventions_version": CONVENTIONS_VERSION, "n": 3}


def check(data):
    return validate_versioned(
        "x.json", data, Doc, kind_key="kind", kind="solidkit-doc", version_key="version", version=2, what="doc"
    )


def test_a_good_document_validates():
    assert check(dict(GOOD)).n == 3


@pytest.mark.parametrize(
    "change, error, message",
    [
        ({"kind": "other"}, InputError, "x.json: not a solidkit doc"),
        ({"version": 1}, InputError, "x.json: doc schema version 1; this solidkit reads 2"),
        (
            {"conventions_version": CONVENTIONS_VERSION + 1},
            ConventionsError,
            "x.json: written under conventions version",
        ),
        ({"n": "many"}, InputError, "x.json: invalid doc: n"),
    ],
)
def test_each_check_is_one_line(change, error, message):
    with pytest.raises(error) as info:
        check({**GOOD, **change})
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def test_finite_documents_refuse_numbers_past_the_float_range(tmp_path) -> None:
    from solidkit.document import DocumentError, read_json_object

    path = tmp_path / "doc.json"
    path.write_text('{"weights": {"sun": 1e400}}')
    assert read_json_object(path)["weights"]["sun"] == float("inf")  # what Python's json makes of it
    with pytest.raises(DocumentError, match=r"doc.json: not a JSON document \(1e400 is out of the float range\)"):
        read_json_object(path, finite=True)  # was inf: testset validate then failed to hash it (exit 1)
