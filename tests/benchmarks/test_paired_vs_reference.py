"""benchmarks/paired_vs_reference.py: --pair reads labels that carry options on either side."""

from __future__ import annotations

import pytest
from conftest import load_benchmark

split_pair = load_benchmark("paired_vs_reference").split_pair


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("igr=igr[profile=standard]", ("igr", "igr[profile=standard]")),
        ("pointr[weights=local]=pointr", ("pointr[weights=local]", "pointr")),
        ("a[x=1,y=2]=b[z=3]", ("a[x=1,y=2]", "b[z=3]")),
        ("occnet", ("", "")),
        ("occnet[a=1]", ("", "")),
    ],
)
def test_pair_splits_at_the_equals_sign_outside_brackets(text, expected):
    assert split_pair(text) == expected
