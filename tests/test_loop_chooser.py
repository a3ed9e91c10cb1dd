"""The thread-loop chooser: the warm-up call is not timed, a short calibration decides, and a probe's time replaces a stale one."""

from bogie_env.simulator import PARALLEL_MIN_ROWS, LoopChooser


def _drive(chooser: LoopChooser, seconds_per_loop, calls: int) -> list[int]:
    chosen = []
    for _ in range(calls):
        chooser.calls += 1
        loop = chooser.choose()
        chooser.record(loop, seconds_per_loop(loop, chooser.loop_calls[loop]))
        chosen.append(loop)
    return chosen


def test_a_slow_first_call_does_not_condemn_the_pool():
    chooser = LoopChooser(PARALLEL_MIN_ROWS, 2)

    def seconds(loop, calls_so_far):  # the pool's first call loads kernels and starts threads
        if loop == 1 and calls_so_far == 0:
            return 2.0
        return 0.010 if loop == 0 else 0.005

    chosen = _drive(chooser, seconds, 50)
    assert chosen[-20:] == [1] * 20


def test_a_probe_replaces_a_stale_slow_figure():
    chooser = LoopChooser(PARALLEL_MIN_ROWS, 2)
    busy = {"until": 30}

    def seconds(loop, calls_so_far):  # the host is busy for the first calls: the pool suffers
        if loop == 1:
            return 0.050 if chooser.calls < busy["until"] else 0.005
        return 0.010

    chosen = _drive(chooser, seconds, 2 * LoopChooser.PROBE_EVERY + 10)
    assert chosen[5:25] == [0] * 20  # the calling thread while the pool is slow
    assert chosen[-5:] == [1] * 5  # back on the pool after the first probe once the load is gone


def test_small_batches_stay_on_the_calling_thread():
    assert not LoopChooser(PARALLEL_MIN_ROWS - 1, 2).enabled
    assert not LoopChooser(4096, 1).enabled


def test_the_choice_is_made_after_the_warm_up_and_two_pairs_of_calls():
    chooser = LoopChooser(PARALLEL_MIN_ROWS, 2)
    noisy = {2: 0.030}  # the calling thread's first timed call was slowed by the host

    def seconds(loop, calls_so_far):
        if loop == 1:
            return 2.0 if calls_so_far == 0 else 0.008
        return noisy.get(chooser.calls, 0.010)

    chosen = _drive(chooser, seconds, 40)
    assert chosen[:5] == [1, 0, 1, 0, 1]  # warm-up on the pool, then the loops alternate
    assert chosen[5:] == [1] * 35  # the pool, from the sixth call on
    assert chooser.seconds == [0.010, 0.008]  # the warm-up is not timed; the fastest call counts


def test_the_calling_thread_wins_when_the_pool_is_slow_from_the_start():
    chooser = LoopChooser(PARALLEL_MIN_ROWS, 2)
    chosen = _drive(chooser, lambda loop, _: 0.030 if loop == 1 else 0.010, 60)
    assert chosen[5:] == [0] * 55


def test_the_packed_serial_step_is_the_unpacked_one():
    """Below PARALLEL_MIN_ROWS the task steps through one packed argument (StepArgs); it must be
    the same arithmetic on the same arrays as the kernel called with the arrays one by one."""
    import numpy as np

    from bogie_env.envs.config import make_config
    from bogie_env.envs.task import HuntingTask, _step_serial

    tasks = [HuntingTask(3, make_config(variant="v2")) for _ in range(2)]
    for task in tasks:
        task.seed_rows(np.arange(3), [1, 2, 3])
        task.reset_rows(np.arange(3), None)
    actions = np.random.default_rng(0).uniform(-1.2, 1.2, (40, 3, tasks[0].action_dim))
    for a in actions:
        tasks[0].step(a)
        assert _step_serial(a, *tasks[1]._step_args()) == -1
    assert tasks[0]._packed_step_args is not None
    for name in ("x", "obs", "reward", "info", "flags"):
        np.testing.assert_array_equal(getattr(tasks[0], name), getattr(tasks[1], name), err_msg=name)
    for task in tasks:  # the packed arrays are the task's own, not copies
        task.states[1] += 1e-3
    tasks[0].step(actions[0])
    _step_serial(actions[0], *tasks[1]._step_args())
    np.testing.assert_array_equal(tasks[0].states, tasks[1].states)


def test_a_stepped_task_pickles_and_copies_and_steps_on_its_own_arrays():
    """The packed step arguments are not pickled or copied; a copy steps its own arrays."""
    import copy
    import pickle

    import numpy as np

    from bogie_env.envs.config import make_config
    from bogie_env.envs.task import HuntingTask

    task = HuntingTask(2, make_config(variant="v2"))
    task.seed_rows(np.arange(2), [4, 5])
    task.reset_rows(np.arange(2), None)
    action = np.full((2, task.action_dim), 0.3)
    task.step(action)
    for duplicate in (lambda t: pickle.loads(pickle.dumps(t)), copy.deepcopy):
        twin = duplicate(task)
        before = task.states.copy()
        twin.step(action)
        np.testing.assert_array_equal(task.states, before)  # the original is untouched
        task.step(action)
        np.testing.assert_array_equal(twin.states, task.states)
