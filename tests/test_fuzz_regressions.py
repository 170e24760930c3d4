"""What the schemathesis fuzz job (test_fuzz_schemathesis) found, one test each."""

from __future__ import annotations


def test_rejected_offset_beyond_64_bits_is_a_400(client):
    """``offset=33769904386475667116615794688`` reached SQL and failed there (500)."""
    for offset in ("33769904386475667116615794688", "9223372036854775808", str(10**18)):
        r = client.get("/v2/notify/rejected", params={"offset": offset})
        assert r.status_code == 400, (offset, r.text)
        assert r.json()["error"] == "BadRequest"
    # The largest integer any parameter takes (history.params.MAX_INT_PARAM, 2^53 - 1) is accepted.
    assert client.get("/v2/notify/rejected", params={"offset": str(2**53 - 1)}).json() == []
