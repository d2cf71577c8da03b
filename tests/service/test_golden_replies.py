"""The service's replies are the recorded bytes (tests/service/golden): a refactor changes no reply.

Rewrite the fixture only for a change meant to alter replies: `python -m tests.service.golden --write`.
"""

import pytest

from .golden import COMMAND, RECORDED_WITH, VARIANTS, differences, environment, is_numeric, load, replay, served

GOLDEN = load()
CASES = {case["request"]["name"]: case for case in GOLDEN["cases"]}


@pytest.fixture(scope="module")
def replies() -> dict[tuple[str, str], dict]:
    """Every recorded request replayed on every variant: {(variant, name): reply}."""
    out = {}
    for variant in VARIANTS:
        with served(variant) as client:
            out.update({(variant, name): replay(client, case["request"]) for name, case in CASES.items()})
    return out


def test_the_fixture_names_each_case_once_and_covers_every_kind_of_reply():
    assert len(CASES) == len(GOLDEN["cases"])
    statuses = {case["reply"]["status"] for case in GOLDEN["cases"]}
    assert {101, 200, 400, 404, 405, 406, 413, 415, 422} <= statuses
    paths = {case["request"]["path"].split("?")[0] for case in GOLDEN["cases"]}
    assert {"/predict", "/estimate", "/plan", "/model", "/openapi.json", "/estimate/stream"} <= paths
    assert GOLDEN["recorded_with"] == RECORDED_WITH


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("name", CASES)
def test_reply_is_the_recorded_bytes(replies, variant, name):
    case = CASES[name]
    differ = differences(GOLDEN["environment"], environment(), numeric=is_numeric(case))
    if differ:
        pytest.skip(f"recorded in another environment ({'; '.join(differ)}); rewrite with {COMMAND}")
    assert replies[(variant, name)] == case["reply"]


@pytest.mark.parametrize("name", CASES)
def test_every_serving_path_gives_the_same_bytes(replies, name):
    """Batched, decoded on the event loop, or unbatched: one reply, in any environment."""
    first, *others = (replies[(variant, name)] for variant in VARIANTS)
    assert all(other == first for other in others)
