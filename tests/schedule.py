"""The order the suite's tests start in: the longest first.

`make test` runs the suite on six workers (pytest-xdist). Collected in file
order, a test of a minute or more near the end (the field page in a browser:
tests/test_web_browser.py) started after most others had finished and ran
alone for its whole length. Collected first, the long tests run beside the
short ones. They must also be handed out one at a time (`--maxschedchunk=1`,
in the Makefile): by default xdist gives each worker a first chunk of a quarter
of its share, in order, and one worker got every long test (10 min 42 s against
4 min 42 s unsorted, on two idle cores).

`LONGEST_S` is each long test's time on two idle cores, measured with
`make test PYTEST_ARGS=--durations=40`, rounded, by the test's name (without
the parameters of a parametrised one). Only the order depends on it: a figure
out of date, or a test missing from it, makes the suite slower, never wrong.
"""

from __future__ import annotations

import pytest

LONGEST_S = {
    "test_the_field_page_through_a_day_at_a_phones_and_a_laptops_width": 101,
    "test_a_lines_survey_end_to_end_has_a_real_surveys_density_and_maps": 47,
    "test_install_twice_then_uninstall": 38,
    "test_status_and_web_find_a_running_simulation_as_its_header_says": 30,
    "test_a_two_station_survey_at_demo_pace": 29,
    "test_simulate_runs_a_survey_on_the_gpio_winch_with_mock_pins": 26,
    "test_two_simulations_in_one_directory_each_judge_only_their_own": 20,
    "test_a_reader_that_leaves_mid_cast_does_not_strand_the_probe": 20,
    "test_a_survey_against_each_firmware_profile": 18,
    "test_the_duty_journals_late_replies_flagged_at_the_time_asked": 17,
    "test_late_replies_are_never_taken_for_a_later_request": 17,
    "test_sighup_mid_cast_reloads_and_the_cast_completes": 16,
    "test_silent_trickling_and_idle_keep_alive_connections_are_closed": 16,
    "test_a_pulled_cable_mid_cast_is_survived": 14,
    "test_m_resent_throughout_the_cast_still_gives_one_cast_per_station": 13,
    "test_a_member_holding_1100_connections_takes_no_descriptor_the_daemon_needs": 13,
    "test_bottom_contact_stops_the_descent": 12,
    "test_the_terminal_going_away_mid_cast_changes_nothing": 11,
    "test_encoder_dead_on_the_mock_drum_halts_the_survey_with_the_reckoned_depth": 11,
    "test_stranded_hauling_in_sends_r_l_until_the_stick_brings_it_home": 11,
    "test_m_resent_every_half_second_makes_exactly_one_cast": 10,
    "test_a_long_surveys_geojson_is_streamed_in_bounded_memory": 10,
    "test_the_port_vanishing_mid_cast_is_survived": 10,
    "test_winch_home_with_the_daemon_running_hauls_a_stranded_probe_in": 9,
    "test_unplugged_sonde_during_a_cast": 9,
    "test_status_while_a_cast_runs_and_after": 9,
    "test_a_probe_that_cannot_come_home_gets_no_r_f_and_fails_the_run": 9,
    "test_a_stranded_probe_is_reported_loudly_and_never_finished": 8,
    "test_a_switch_stuck_closed_on_the_mock_drum_halts_the_survey_honestly": 8,
    "test_lost_pulses_are_corrected_at_the_switch_with_both_figures": 8,
    "test_a_stall_hauling_in_strands_the_probe_loudly": 8,
    "test_a_cast_with_a_sonde_descends_no_faster_than_its_profile_resolves": 8,
    "test_simulate_autopilot_on_a_serial_port_against_a_daemon": 8,
}


def seconds(item: pytest.Item) -> int:
    """A test's time in `LONGEST_S`, 0 if not there."""
    return LONGEST_S.get(item.name.split("[", 1)[0], 0)


def longest_first(items: list[pytest.Item]) -> None:
    """Put the longest tests first; the others keep the order they were collected in.
    Every worker collects, and so sorts, the same way (pytest-xdist requires it)."""
    items.sort(key=lambda item: -seconds(item))
