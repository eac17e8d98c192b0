"""Suite-wide DDS isolation (see domains.py): the run never joins the user's ROS graph or another run's.

At start the run leases one domain id for itself and puts it in ``ROS_DOMAIN_ID``, with
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and without the shell's DDS configuration
(``domains.FOREIGN_DDS_ENV``): every process a test starts without choosing a domain - a CLI
call, a launch - talks on that private domain, on loopback. A test that needs a domain of its
own takes the ``domain_id`` fixture (or ``module_domain_id``).

numba: the run sets ``NUMBA_CACHE_DIR`` (``dem_ros.core.numba_cache``: the cache of this version of the
core's sources) for every process a test starts, and when the suite has not yet filled that cache for this
checkout (the first run after an edit of ``dem_ros/core``, or the first run of another checkout of the same
version: the directory is keyed by the sources' contents, but numba keeps kernels per source *path*, see
``dem_ros.tools.common.warm_kernels``) compiles the kernels into it once, here, with progress: otherwise
every node process of the first graph test compiles the same kernels at once, and on a loaded 2-core
machine they were not ready within the launcher's 120 s. The marker that says so is keyed the same way
(:func:`warm_marker`). Only tests/tools/test_first_use.py uses an empty cache of its own (it proves first use).

Tiers (markers registered in pyproject.toml; ``make test-fast`` runs ``-m "unit and not slow"``): a test is
``graph`` when it starts real processes or joins DDS: it takes a domain fixture (``domain_id``,
``module_domain_id``), or carries the marker itself, or is listed in :data:`GRAPH` (tests that start a process
without a domain: CLI runs, a C compiler, a Dask cluster, a child that crashes on purpose); every other test is
``unit``. :data:`SLOW` lists the long ones of either tier. A ``unit`` test that starts a process anyway (subprocess,
fork, posix_spawn, multiprocessing) fails with a line that says so, so the tiers cannot drift from what the tests do.
"""

from __future__ import annotations

import hashlib
import multiprocessing.process
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import domains
import pytest

_session: domains.DomainLease | None = None


#: tests (a module, or module::test, relative to tests/) that start a process without a domain fixture: the graph tier
GRAPH: frozenset[str] = frozenset({
    "bag/test_check_errors.py::test_bag_package_imports_no_middleware",  # a child interpreter
    "bag/test_check_errors.py::test_cli_prints_error_without_traceback",
    "bag/test_crash.py",  # a recorder child killed on purpose
    "bag/test_faults.py::test_full_disk_in_the_writer_raises_one_bag_error_then_refuses",  # a tmpfs mounted
    "bag/test_faults.py::test_full_disk_stops_the_recorder_cleanly_reports_at_once_and_keeps_what_was_written",
    "bag/test_faults.py::test_recorder_counters_survive_a_full_disk_in_a_child_that_exits",
    "bag/test_recorder_node_disk_full.py",
    "board/test_board_no_middleware.py",  # a clean interpreter probes the imports
    "firmware/test_differential.py",  # the firmware compiled for the host
    "firmware/test_firmware_c.py",
    "graph/test_rclpy_transport.py",
    "graph/test_recorder_starved.py",
    "graph/test_shutdown_signals.py",
    "tools/test_identify_cli.py",  # emulated rig runs
    "tools/test_identify_calibrate.py",
    "tools/test_identify_launch.py",
    "tools/test_verdicts.py",
    "tools/test_view.py",
    "transport/test_param_answers.py",
    "core/test_no_middleware.py",  # a clean interpreter probes the imports
    "graph/test_command_lock.py",
    "graph/test_diagnostics_graph.py",
    "graph/test_composed.py",
    "graph/test_free_run.py",
    "graph/test_graph.py",
    "graph/test_rclpy_graph.py",
    "graph/test_recorder_node.py",
    "graph/test_recorder_stall.py",
    "hardware/test_driver_node.py",
    "hardware/test_hw_lifecycle.py",
    "hardware/test_hw_restart.py",
    "hardware/test_link_c.py",  # the C codec compiled and run
    "hardware/test_link_channel.py::test_linkbench_cli",  # the link benchmark as a command
    "hardware/test_link_channel.py::test_linkbench_runs",
    "hardware/test_rig_config_process.py",
    "hardware/test_rig_launch.py",
    "hardware/test_rig_process.py",
    "test_domains.py::test_the_run_has_its_own_domain_and_no_foreign_dds_config",
    "test_domains.py::test_ids_held_by_another_process_are_leased_only_after_it_dies",
    "test_realtime.py::test_without_rt_permission_one_warning_line_and_the_loop_runs",
    "test_realtime.py::test_granted_where_permitted",
    "test_realtime.py::test_priority_0_is_off_the_loop_s_path_normal_scheduling_at_nice_minus_10",
    "test_realtime.py::test_blas_computes_on_the_loop_thread_only",
    "test_realtime.py::test_rt_off_leaves_the_process_alone",
    "test_realtime.py::test_graph_without_rt_permission_warns_once_runs_and_leaves_no_cyclic_garbage",
    "test_realtime.py::test_a_stall_spent_preempted_by_a_higher_priority_thread_is_runnable",
    "test_realtime.py::test_a_real_time_thread_that_stops_sleeping_is_put_back_to_normal_scheduling",
    "test_realtime.py::test_leave_loop_is_idempotent_and_counts_what_it_changed",
    "test_realtime.py::test_tty_workers_run_at_fifo_meanwhile_and_get_their_policy_back",
    "test_realtime.py::test_the_tty_workers_wrapper_runs_the_command_and_passes_its_exit_code",
    "tools/test_bench_loop.py",
    "tools/test_fault_catalogue.py",
    "tools/test_faults_launch.py",
    "tools/test_first_use.py",
    "tools/test_lint.py",  # ruff and mypy
    "tools/test_mistakes.py::test_mistake_is_one_line_exit_2_nothing_written",
    "tools/test_node_cli.py",
    "tools/test_progress.py::test_a_command_that_cannot_run_still_shows_its_elapsed_time",
    "tools/test_replay.py::test_replay_cli_writes_json_and_figures",  # dem-ros replay as a command
    "tools/test_replay.py::test_corrupt_or_foreign_input_is_a_clear_error",
    "tools/test_replay_figures.py::test_replay_and_sim_draw_the_same_figures",
    "tools/test_runmetrics.py::test_sim_help_states_the_configured_command_delay",
    "tools/test_study.py::test_study_on_a_local_cluster_writes_rows_maps_and_resumes",  # a Dask cluster
    "tools/test_study.py::test_results_of_another_study_are_not_mixed_in",
    "tools/test_study.py::test_study_against_a_separate_scheduler_and_worker",
    "tools/test_study.py::test_bad_arguments_give_one_line_and_exit_2",
    "tools/test_study.py::test_an_unreachable_scheduler_is_one_line_within_the_timeout",
    "transport/test_composition.py",
    "transport/test_dds_graph.py",
    "transport/test_sources.py",
})

#: the long tests of either tier (module, or module::test), left out of ``make test-fast``
SLOW: frozenset[str] = frozenset({
    # the longest of the unit tier (seconds each; make test runs them): make test-fast stays within 3 minutes
    # (the four on the independently integrated coil data: its module fixture takes most of a minute)
    "core/test_identify.py::test_integrated_coil_equations_recover_R1_R2_K1_K2_from_independently_integrated_data",
    "core/test_identify.py::test_coil_simulation_matches_the_independent_integration",
    "core/test_identify.py::test_excited_coils_identify_R1_R2_K1_K2_with_truth_inside_the_intervals",
    "core/test_identify.py::test_excited_coils_of_magnets_alike_give_one_K",
    "board/test_board_hashes.py::test_board_outputs_are_bit_for_bit",
    "graph/test_restart.py::test_controller_killed_the_board_lands_then_a_restarted_controller_and_arm_lift_off_again",
    "graph/test_restart.py::test_a_landing_during_the_lift_off_then_an_arm_at_once_lifts_off_again_without_a_trip",
    "graph/test_restart.py::test_a_lift_off_with_a_command_delay_is_as_smooth_as_without",
    "hardware/test_rig.py::test_a_stuck_gap_sensor_is_found_by_the_flux_check_and_the_plate_landed",
    "hardware/test_rig.py::test_s1_through_the_board_models_in_lockstep_tracks_as_offline",
    "board/test_safety.py::test_worst_commands_never_reach_the_rail",
    "board/test_safety.py::test_seeded_random_approaches_never_reach_the_rail",
    "tools/test_exit_codes.py::test_replay_tells_samples_the_recorder_lost_from_a_reference_outage",
    "tools/test_exit_codes.py::test_replay_flags_stretches_without_a_reference_as_degraded_exit_3",
    "tools/test_exit_codes.py::test_bag_info_and_check_exit_1_with_problems",
    "core/test_model.py::test_decoupling_matrix_and_its_determinant",  # sympy
    "core/test_identify.py::test_intervals_cover_the_truth_under_correlated_residuals",
    "core/test_adaptive_rig.py::test_gap_sensor_offset_is_a_bounded_offset_not_a_drift",
    "core/test_adaptive_rig.py::test_S5_coil_heating_tracked_below_10um",
    "core/test_adaptive_rig.py::test_S6_off_centre_load_no_failure",
    "core/test_controllers.py::test_exact_linearisation_with_true_parameters",
    "core/test_estimator.py::test_bias_state_absorbs_unknown_mass",
    "core/test_estimator.py::test_noise_is_reduced",
    "bag/test_check_errors.py::test_check_complete_bag",
    "fuzz/test_node_fuzz.py",
    "firmware/test_differential.py",
    "graph/test_shutdown_signals.py",
    "graph/test_rclpy_transport.py",
    "tools/test_identify_launch.py",
    "fuzz/test_decode_fuzz.py::test_joint_state_fast_path_and_generic_decoder_agree_on_mutated_input",
    "hardware/test_hw_lifecycle.py",
    "hardware/test_hw_restart.py",
    "tools/test_fault_catalogue.py",
    "tools/test_faults_launch.py",
    "tools/test_first_use.py",
    "tools/test_lint.py",
    "tools/test_study.py::test_study_on_a_local_cluster_writes_rows_maps_and_resumes",
    "tools/test_study.py::test_study_against_a_separate_scheduler_and_worker",
})

#: fixtures that join DDS (a leased domain): a test that takes one is ``graph``
_DOMAIN_FIXTURES = frozenset({"domain_id", "module_domain_id"})


def _listed(nodeid: str, names: frozenset[str]) -> bool:
    """Whether ``nodeid`` (``tests/x/test_y.py::test_z[param]``) is listed in ``names`` by module or by test."""
    path, _, name = nodeid.partition("::")
    path = path.removeprefix("tests/")
    return path in names or f"{path}::{name.split('[')[0]}" in names


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        graph = (item.get_closest_marker("graph") is not None or bool(_DOMAIN_FIXTURES & set(item.fixturenames))
                 or _listed(item.nodeid, GRAPH))
        item.add_marker(pytest.mark.graph if graph else pytest.mark.unit)
        if _listed(item.nodeid, SLOW):
            item.add_marker(pytest.mark.slow)


#: the unit test running now (its set-up, call and teardown), or None: a process started then is refused
_unit_test: list[str | None] = [None]
_refused: dict[str, str] = {}


def _refuse_in_unit_tier(what: str, start: Callable[..., Any]) -> Callable[..., Any]:
    def guarded(*args: Any, **kwargs: Any) -> Any:
        nodeid = _unit_test[0]
        if nodeid is not None:
            _refused.setdefault(nodeid, what)
            raise RuntimeError(f"a unit test started a process ({what}): mark it graph (tests/conftest.py, GRAPH)")
        return start(*args, **kwargs)

    return guarded


def _guard_processes() -> None:
    """Wrap every way this interpreter starts a process so that the unit tier cannot."""
    subprocess.Popen._execute_child = _refuse_in_unit_tier(  # type: ignore[attr-defined]
        "subprocess", subprocess.Popen._execute_child)  # type: ignore[attr-defined]
    for name in ("fork", "forkpty", "posix_spawn", "posix_spawnp"):
        if hasattr(os, name):
            setattr(os, name, _refuse_in_unit_tier(f"os.{name}", getattr(os, name)))
    base = multiprocessing.process.BaseProcess
    base.start = _refuse_in_unit_tier("multiprocessing", base.start)  # type: ignore[method-assign]


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    _unit_test[0] = item.nodeid if item.get_closest_marker("unit") is not None else None
    try:
        yield
    finally:
        _unit_test[0] = None


@pytest.fixture(autouse=True)
def _unit_tier_starts_no_process(request: pytest.FixtureRequest) -> Iterator[None]:
    """Fails a unit test that started a process, also where the refusal was caught (a thread, a broad except)."""
    yield
    what = _refused.pop(request.node.nodeid, None)
    if what is not None:
        pytest.fail(f"a unit test started a process ({what}): mark it graph (tests/conftest.py, GRAPH)")


def pytest_configure(config: pytest.Config) -> None:
    global _session
    _guard_processes()
    _session = domains.lease()
    for name in domains.FOREIGN_DDS_ENV:
        os.environ.pop(name, None)
    os.environ["ROS_DOMAIN_ID"] = str(_session.id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    _fill_numba_cache()


def warm_marker(cache: str) -> Path:
    """The file in numba cache directory ``cache`` that says the suite compiled every kernel of *this checkout*
    into it: keyed as numba keys the kernels, by the absolute path of the sources' directory
    (``<cache>/core_<sha1 of that path>``, what ``dem_ros.tools.common.warm_kernels`` looks at; abspath, not
    resolve, as numba does), not only by the sources' contents (the cache directory's key)."""
    import dem_ros.core

    core = os.path.abspath(os.path.dirname(dem_ros.core.__file__))
    return Path(cache) / f"warmed-by-tests-core_{hashlib.sha1(core.encode()).hexdigest()}"


def _fill_numba_cache() -> None:
    """Point this run and its child processes at the shared numba cache; compile into it once if this
    checkout's kernels are not all in it."""
    from dem_ros.core.numba_cache import configure

    done = warm_marker(configure())  # every kernel is in (not only those a killed process wrote)
    if done.exists():
        return  # each process loads what it needs
    from dem_ros.tools.common import warm_kernels

    warm_kernels("tests", stream=sys.stderr)  # compiles what is missing, loads the rest (seconds)
    done.touch()


def pytest_unconfigure(config: pytest.Config) -> None:
    if _session is not None:
        _session.release()


@pytest.fixture
def domain_id(monkeypatch: pytest.MonkeyPatch) -> Iterator[int]:
    """A DDS domain of this test's own, set as ``ROS_DOMAIN_ID`` (loopback, Jazzy conventions) for its life."""
    with domains.lease() as d:
        monkeypatch.setenv("ROS_DOMAIN_ID", str(d))
        monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        monkeypatch.delenv("DEM_ROS_DISTRO", raising=False)
        yield d


@pytest.fixture(scope="module")
def module_domain_id() -> Iterator[int]:
    """A DDS domain held for the test module's life (for module-scoped runs; the environment is not changed)."""
    with domains.lease() as d:
        yield d
