"""The suite's order (tests/schedule.py): the longest tests start first, and every test
the schedule names is one the suite has."""

from __future__ import annotations

import pytest

from tests import schedule


def test_the_longest_tests_are_collected_first(request: pytest.FixtureRequest) -> None:
    items = request.session.items
    times = [schedule.seconds(item) for item in items]
    assert times == sorted(times, reverse=True)
    if any(times):  # whole files or the whole suite: the longest of them leads
        assert schedule.seconds(items[0]) == max(times)


def test_every_test_the_schedule_names_is_in_the_suite(request: pytest.FixtureRequest) -> None:
    items = request.session.items
    if len(items) < 1000:
        pytest.skip("part of the suite was collected: the schedule is checked on the whole")
    names = {item.name.split("[", 1)[0] for item in items}
    assert sorted(set(schedule.LONGEST_S) - names) == []


def test_a_test_not_named_keeps_its_place(request: pytest.FixtureRequest) -> None:
    """Only the named tests move: the others run in the order they were written."""
    items = request.session.items
    rest = [item.nodeid for item in items if schedule.seconds(item) == 0]
    mine = [nodeid for nodeid in rest if nodeid.startswith("tests/test_schedule.py::")]
    assert mine == [
        "tests/test_schedule.py::test_the_longest_tests_are_collected_first",
        "tests/test_schedule.py::test_every_test_the_schedule_names_is_in_the_suite",
        "tests/test_schedule.py::test_a_test_not_named_keeps_its_place",
    ]
