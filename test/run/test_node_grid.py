"""The tick grid alone (no rclpy, no node): stamps, indices, anchors, due sensor samples."""

import numpy as np

from rigidrot_ros.run import grid


def test_index_is_the_last_stamp_at_or_before_now_for_awkward_rates():
    """index(now) = max{k: stamp(k) <= now}, checked by brute force against stamp()."""
    rng = np.random.default_rng(17)
    for rate in (100.0, 3.0, 7.0, 1e4, 1e-3, 33.333333333333336, 1000.0 / 7.0):
        origin = int(rng.integers(0, 2 ** 62))
        for _ in range(200):
            now = origin + int(rng.integers(-10 ** 9, 5 * 10 ** 9))
            k = grid.index(origin, rate, now)
            assert grid.stamp_ns(origin, rate, k) <= now < grid.stamp_ns(origin, rate, k + 1)


def test_stamps_are_one_rounding_of_origin_plus_k_over_rate():
    assert grid.stamp_ns(5, 3.0, 1) == 5 + 333_333_333
    assert grid.stamp_ns(5, 3.0, 2) == 5 + 666_666_667      # rounded once, not summed
    assert grid.stamp_ns(0, 100.0, 100) == 1_000_000_000
    assert [grid.stamp_ns(10, 40.0, k) for k in range(3)] == [10, 25_000_010, 50_000_010]


def test_anchor_is_the_scheduled_time_of_the_call_being_served():
    period = 10_000_000
    # served 3 ms late: the next call is 7 ms away, so this call was due at now - 3 ms
    assert grid.anchor_ns(1_000_003_000_000, 7_000_000, period) == 1_000_000_000_000
    assert grid.anchor_ns(123, None, period) == 123                # no timer to ask
    assert grid.anchor_ns(123, 2 * period, period) == 123          # not a plausible schedule
    assert grid.anchor_ns(1_000, 0, period) == 0                   # a sim clock starts at 0


def test_after_a_rate_change_the_new_grid_has_its_own_anchor_and_scene_clock_runs_on():
    """The stamp formula after a runtime rate change: g' + j / rate', t from t_start."""
    t_start = 1_000_000_000
    k_before = grid.index(t_start, 100.0, t_start + 123_456_789)       # 12 ticks at 100 Hz
    assert k_before == 12
    g1 = t_start + 123_456_789                                          # the new timer's call
    stamps = [grid.stamp_ns(g1, 40.0, j) for j in range(3)]
    assert np.all(np.diff(stamps) == 25_000_000)
    assert (stamps[0] - t_start) % 10_000_000 != 0                      # off the old grid
    assert (stamps[0] - t_start) % 25_000_000 != 0                      # and off t_start's


def test_due_sensor_samples_and_a_clock_jump():
    t0 = 1_000_000_000
    assert grid.due(t0, 100.0, 0, t0 + 35_000_000) == (1, 3, 0)
    assert grid.due(t0, 100.0, 3, t0 + 35_000_000) == (4, 3, 0)         # none due
    assert grid.due(t0, 100.0, 0, t0 - 5) == (1, 0, 0)                  # before t_start
    assert grid.due(t0, 100.0, 0, t0 + 5_000_000_000) == (500, 500, 499)
    assert grid.due(t0, 100.0, 0, t0 + 1_000_000_000) == (1, 100, 0)    # a second: kept
    assert grid.due(t0, 1.0, -1, t0 + 9_000_000_000) == (0, 9, 0)       # cap is 10 at <10 Hz
    assert grid.due(t0, 1.0, -1, t0 + 12_000_000_000) == (12, 12, 12)


def test_due_truth_ticks_a_late_call_a_clock_jump_and_a_clock_that_went_back():
    g = 1_000_000_000
    assert grid.truth_due(g, 100.0, -1, g) == (0, 0, 0)                   # the first tick
    assert grid.truth_due(g, 100.0, 0, g + 35_000_000) == (1, 3, 0)      # late: 3 owed
    assert grid.truth_due(g, 100.0, 3, g + 35_000_000) is None            # published
    assert grid.truth_due(g, 100.0, 4, g + 35_000_000) is None            # one ahead: too
    assert grid.truth_due(g, 100.0, 5, g + 35_000_000) is grid.NEW_GRID   # went back
    assert grid.truth_due(g, 100.0, 0, g + 1_000_000_000) == (1, 100, 0)     # 99 owed: kept
    assert grid.truth_due(g, 100.0, 0, g + 1_010_000_000) == (101, 101, 100)  # 100: skipped
    assert grid.truth_due(g, 2.0, 0, g + 5_000_000_000) == (1, 10, 0)     # below 10 Hz the
    assert grid.truth_due(g, 2.0, 0, g + 5_500_000_000) == (11, 11, 10)   # cap is 10 ticks


def test_a_run_is_set_up_and_sampled_without_a_node():
    """prepare_run -> the table's outputs -> messages and the run description, no rclpy node."""
    import pytest
    from rigidrot_ros.run import params, settings
    from rigidrot_ros.run import outputs
    from run_helpers import per_sample, sensors
    values = params.defaults()
    values.update({'imu.enable': True, 'star_tracker.enable': True, 'imu.rate': 200.0})
    setup = settings.prepare_run(values)
    imu, star = sensors(setup)
    assert (imu.rate, star.rate, imu.first, star.first) == (200.0, 10.0, 1, 0)
    t0 = 7_000_000_000
    msgs = per_sample(imu, 1, t0, setup.time_scale, setup.frames)
    assert [topic for topic, _ in msgs] == ['imu', 'delta_angle', 'delta_rotation']
    stamp = msgs[0][1].header.stamp
    assert stamp.sec * 10 ** 9 + stamp.nanosec == t0 + 5_000_000
    assert msgs[0][1].header.frame_id == 'body'
    (topic, st), = per_sample(star, 0, t0, setup.time_scale, setup.frames)
    assert topic == 'star_tracker' and st.header.frame_id == 'inertial'
    info = outputs.run_description(setup, t0, 1, '/attitude_node', {'/attitude': 'x'})
    assert info['start_ns'] == t0 and info['model'] == setup.solution.model
    assert info['scene'] == setup.solution.scene.as_dict()
    with pytest.raises(ValueError, match='parameter imu.rate must be 0'):
        settings.prepare_run({**values, 'imu.rate': 1e-9})
    with pytest.raises(ValueError, match='parameter qos_depth is missing'):
        settings.prepare_run({k: v for k, v in values.items() if k != 'qos_depth'})
