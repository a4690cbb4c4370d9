"""The suite's own mechanisms in tests/conftest.py: the extended tier and the check that xdist can group."""
from __future__ import annotations

import types

import pytest

from tests.conftest import extended_cases, xdist_can_group


def _item(name, extended):
    mark = pytest.mark.extended.mark if extended else None
    return types.SimpleNamespace(nodeid=name, get_closest_marker=lambda m, mark=mark: mark if m == "extended" else None)


def test_the_extended_cases_are_deselected_unless_asked_for_and_the_order_is_kept():
    items = [_item("a", False), _item("b", True), _item("c", False), _item("d", True)]
    kept, deselected = extended_cases(items, run_extended=False)
    assert [i.nodeid for i in kept] == ["a", "c"]
    assert [i.nodeid for i in deselected] == ["b", "d"]
    kept, deselected = extended_cases(items, run_extended=True)
    assert [i.nodeid for i in kept] == ["a", "b", "c", "d"] and deselected == []


def test_this_pytest_lets_xdist_put_tests_in_their_groups():
    """pytest < 9 (pyproject.toml): xdist's ``@group`` suffix on ``item._nodeid`` is what ``nodeid`` returns."""
    assert xdist_can_group()
