"""Benchmark timing: functions whose ratio is reported are called in turn, round by round."""

import time

from jaxrb.bench.timing import time_alternated, time_compiled


def recording(calls, name, pause_s=0.0):
    def function(value):
        calls.append(name)
        time.sleep(pause_s)
        return value + len(calls)
    return function


def test_alternated_calls_take_turns_after_a_warmup_round():
    calls = []
    forward, grad = recording(calls, "forward"), recording(calls, "grad")
    results = time_alternated((forward, grad), 0, repeats=4, warmup=1)
    assert calls == ["forward", "grad"] * 5
    (forward_s, forward_runs, forward_out), (grad_s, grad_runs, grad_out) = results
    assert len(forward_runs) == len(grad_runs) == 4
    assert (forward_out, grad_out) == (9, 10)  # each function's own last output
    assert min(forward_runs) <= forward_s <= max(forward_runs)


def test_alternated_timing_stops_at_the_budget_after_the_minimum_rounds():
    calls = []
    slow = recording(calls, "slow", pause_s=0.01)
    # a 5 ms budget is spent in the first round, so timing stops after min_repeats
    (median_s, runs, _), = time_alternated((slow,), 0, repeats=10, min_repeats=3, budget_s=0.005, warmup=0)
    assert len(runs) == 3 and median_s >= 0.01
    assert len(time_compiled(slow, 0, repeats=10, min_repeats=2, budget_s=0.005, warmup=0)[1]) == 2
