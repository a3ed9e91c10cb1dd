"""The thread-loop chooser: warm-up calls are not timed, and a probe's time replaces a stale one."""

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
