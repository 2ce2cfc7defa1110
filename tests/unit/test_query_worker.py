"""The Zenoh queries' worker (``canopen_gateway.zenoh_bridge.worker``) driven step by step: a
controlled executor (``step`` is one turn, no thread) and a fake clock. Bounds, round robin
between querying sessions, lazy answers that give way, failures that stop nothing."""

from __future__ import annotations

import threading
from collections.abc import Iterator

from canopen_gateway.runtime.threads import ThreadRegistry
from canopen_gateway.zenoh_bridge.worker import RETRY_MAX_S, RETRY_MIN_S, QueryWorker
from tests.helpers import wait_until_sync


class Log:
    """Jobs that record each unit of work: ``(item, i)``."""

    def __init__(self) -> None:
        self.units: list[tuple[str, int]] = []
        self.finalised: list[str] = []

    def job(self, item: tuple[str, int]) -> Iterator[None]:
        name, n = item
        try:
            for i in range(n):
                self.units.append((name, i))
                yield
        finally:
            self.finalised.append(name)


def worker(log: Log, **kw: object) -> QueryWorker[tuple[str, int]]:
    return QueryWorker(log.job, yield_fn=lambda s: None, **kw)  # type: ignore[arg-type]


def run_all(w: QueryWorker[tuple[str, int]]) -> int:
    turns = 0
    while w.step():
        turns += 1
    return turns


def test_a_long_answer_advances_per_turn_units_per_turn_and_is_never_produced_whole() -> None:
    log = Log()
    w = worker(log, per_turn=4)
    assert w.submit("a", ("history", 1000))
    assert w.step()
    assert log.units == [("history", i) for i in range(4)]  # 4 replies, not 1,000
    assert w.depth == 1
    run_all(w)
    assert len(log.units) == 1000 and log.finalised == ["history"]
    assert (w.answered, w.depth) == (1, 0)


def test_sessions_take_turns_a_short_query_is_not_held_behind_a_long_one() -> None:
    log = Log()
    w = worker(log, per_turn=2)
    w.submit("dashboard", ("everything", 10))
    w.submit("dashboard", ("everything-again", 10))
    w.submit("script", ("state", 1))
    w.step()  # dashboard's first turn
    w.step()  # script's turn: its answer ends
    assert log.finalised == ["state"]
    assert log.units == [("everything", 0), ("everything", 1), ("state", 0)]
    run_all(w)
    assert log.finalised == ["state", "everything", "everything-again"]


def test_past_the_bound_submit_refuses_and_counts_busy_nothing_is_queued() -> None:
    log = Log()
    w = worker(log, queue_max=3, lane_max=2)
    assert w.submit("a", ("a1", 1)) and w.submit("a", ("a2", 1))
    assert not w.submit("a", ("a3", 1))  # the lane's bound
    assert w.submit("b", ("b1", 1))
    assert not w.submit("c", ("c1", 1))  # the queue's bound, whatever the lane
    assert (w.busy, w.depth) == (2, 3)
    run_all(w)
    assert sorted(log.finalised) == ["a1", "a2", "b1"]
    assert w.submit("c", ("c2", 1))  # room again
    assert w.depth == 1


def test_the_retry_hint_is_the_depth_times_the_mean_job_time_within_bounds() -> None:
    now = [0.0]

    def job(item: str) -> Iterator[None]:
        now[0] += 0.1  # every job takes 0.1 s of the fake clock
        yield

    w: QueryWorker[str] = QueryWorker(job, clock=lambda: now[0], yield_fn=lambda s: None)
    assert w.retry_after_s() == RETRY_MIN_S  # an empty queue
    for i in range(60):
        w.submit("a", f"j{i}")
        w.step()
    assert w.depth == 0
    for i in range(50):
        w.submit("a", f"k{i}")
    assert abs(w.retry_after_s() - 50 * 0.1) < 0.05  # 50 waiting, 0.1 s each
    for i in range(200):
        w.submit("b", f"m{i}")
    assert w.retry_after_s() == RETRY_MAX_S


def test_a_job_that_raises_is_dropped_counted_and_the_others_go_on() -> None:
    log = Log()

    def job(item: tuple[str, int]) -> Iterator[None]:
        if item[0] == "bad":
            raise RuntimeError("a bug")
        return log.job(item)

    w: QueryWorker[tuple[str, int]] = QueryWorker(job, yield_fn=lambda s: None)
    w.submit("a", ("bad", 1))
    w.submit("a", ("good", 1))
    run_all(w)
    assert log.finalised == ["good"]
    assert (w.failed, w.answered, w.depth) == (1, 1, 0)


def test_drain_closes_running_answers_and_hands_back_the_queries_never_started() -> None:
    log = Log()
    w = worker(log, per_turn=1)
    w.submit("a", ("running", 5))
    w.submit("a", ("waiting", 5))
    w.step()
    w.stop()
    assert not w.submit("a", ("late", 1))  # stopping: refused, answered busy by the caller
    left = w.drain()
    assert left == [("waiting", 5)]
    assert log.finalised == ["running"]  # its finally ran: the query is finalised
    assert w.depth == 0


def test_the_thread_answers_what_is_submitted_and_stops() -> None:
    log = Log()
    done = threading.Event()

    def job(item: tuple[str, int]) -> Iterator[None]:
        yield from log.job(item)
        done.set()

    threads = ThreadRegistry()
    w: QueryWorker[tuple[str, int]] = QueryWorker(job)
    w.start_thread(threads, "test-queries")
    try:
        w.submit("a", ("one", 3))
        wait_until_sync(done.is_set, 5, "the job answered")
        wait_until_sync(lambda: w.depth == 0, 5, "the queue empty")
        assert w.answered == 1
    finally:
        w.stop()
    assert threads.failures() == {}


def test_a_history_answer_in_a_lane_of_its_own_lets_the_same_clients_short_get_through() -> None:
    """The anonymous clients share one lane; their long answers (history) have another, with
    more replies per turn: a plain get waits for one turn of it, not for the answer."""
    log = Log()
    w = worker(log, per_turn=4)
    assert w.submit(("anonymous", "history"), ("history", 100_000), 16)
    assert w.step()  # the long answer has begun
    assert w.submit("anonymous", ("state", 1))
    assert w.step() and w.step()  # one more turn of the long answer, then the short get's
    assert log.finalised == ["state"]
    assert [u for u in log.units if u[0] == "history"] == [("history", i) for i in range(32)]
