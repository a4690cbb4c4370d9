"""Documents nested deeper than the parsers follow: a clear error naming the file (issue 40, item 7)."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from udrobot_files.nesting import NestingError, loads_json, loads_toml


@settings(max_examples=25, deadline=None)
@given(depth=st.integers(2_000, 200_000), kind=st.sampled_from(["[", '{"a":']))
def test_deep_json_is_a_nesting_error_naming_the_file(depth, kind):
    close = "]" if kind == "[" else "}"
    text = kind * depth + ("1" if kind != "[" else "") + close * depth
    with pytest.raises(NestingError, match=r"^model\.json: JSON nested too deeply"):
        loads_json(text, "model.json")


@settings(max_examples=10, deadline=None)
@given(depth=st.integers(2_000, 50_000))
def test_deep_toml_is_a_nesting_error_naming_the_file(depth):
    with pytest.raises(NestingError, match=r"^map\.toml: TOML nested too deeply"):
        loads_toml("a = " + "[" * depth + "]" * depth + "\n", "map.toml")


def test_ordinary_documents_parse():
    assert loads_json('{"a": [[1]]}', "x") == {"a": [[1]]}
    assert loads_toml("a = [[1]]\n", "x") == {"a": [[1]]}
