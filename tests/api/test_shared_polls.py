"""Event streams of one API process share their polls of the database (`backend.polls.SharedPolls`)."""

from __future__ import annotations

import threading
import time

import anyio

from backend.polls import SharedPolls


def test_streams_asking_at_once_share_one_fetch_and_a_later_question_fetches_again():
    polls = SharedPolls(max_age_s=0.2)
    calls: list[int] = []
    lock = threading.Lock()

    def fetch() -> dict[str, int]:
        time.sleep(0.05)  # a database read: the other streams ask while it runs
        with lock:
            calls.append(1)
            return {"answer": len(calls)}

    async def streams() -> list[dict[str, int]]:
        answers: list[dict[str, int]] = []

        async def one() -> None:
            answers.append(await polls.get(("job", "a"), fetch))

        async with anyio.create_task_group() as group:
            for _ in range(50):
                group.start_soon(one)
        return answers

    answers = anyio.run(streams)
    assert len(answers) == 50 and all(answer == {"answer": 1} for answer in answers)
    assert polls.fetches == 1  # not 50

    async def later() -> dict[str, int]:
        await anyio.sleep(0.25)  # older than max_age_s: asked again
        return await polls.get(("job", "a"), fetch)

    assert anyio.run(later) == {"answer": 2}
    assert anyio.run(polls.get, ("job", "b"), fetch) == {"answer": 3}  # another question is its own


def test_old_answers_are_dropped_once_many_questions_were_asked():
    polls = SharedPolls(max_age_s=0.01)

    async def ask_many() -> None:
        for index in range(SharedPolls.PRUNE_ABOVE + 50):
            await polls.get(("log", index), lambda index=index: index)
        await anyio.sleep(0.05)
        await polls.get(("log", "last"), lambda: "last")

    anyio.run(ask_many)
    # Bounded: however the questions were spread in time (pruning starts above PRUNE_ABOVE keys, so up to that many
    # recent ones may stay), and the oldest answers are gone.
    assert len(polls._kept) <= SharedPolls.PRUNE_ABOVE and len(polls._locks) <= SharedPolls.PRUNE_ABOVE
    assert ("log", 0) not in polls._kept and ("log", 0) not in polls._locks
