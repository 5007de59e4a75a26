"""Concurrent calls on one client: each gets its own response."""

from __future__ import annotations

import asyncio
import threading

from fakeserver import serving

import lluav


def test_fifty_concurrent_calls_on_one_async_client_each_get_their_own_response(lluavd):
    daemon = lluavd()

    async def run() -> None:
        async with lluav.AsyncClient(daemon.url) as c:
            names = [f"task-{i}" for i in range(50)]
            calls = [c.set_taskname(name) if i % 5 else c.state() for i, name in enumerate(names)]
            responses = await asyncio.gather(*calls)
            for i, (name, response) in enumerate(zip(names, responses)):
                if i % 5:
                    assert (response["cmd"], response["taskname"]) == (41, name)
                else:
                    assert response["cmd"] == 2 and "state" in response

    asyncio.run(run())


def test_concurrent_requests_go_out_in_the_order_of_the_calls():
    with serving() as server:

        async def run() -> None:
            async with lluav.AsyncClient(server.url) as c:
                await asyncio.gather(*(c.set_sp_ned(float(i), 0.0, -2.0, 0.0) for i in range(50)))

        asyncio.run(run())
        assert server.frames == [f"set_sp_ned {i}.0:0.0:-2.0:0.0" for i in range(50)]


def test_a_cancelled_call_does_not_shift_the_responses_of_the_others(lluavd):
    daemon = lluavd()

    async def run() -> None:
        async with lluav.AsyncClient(daemon.url) as c:
            tasks = [asyncio.ensure_future(c.set_taskname(f"t{i}")) for i in range(20)]
            await asyncio.sleep(0)
            tasks[7].cancel()
            results = await asyncio.gather(*tasks, return_exceptions=True)
            assert isinstance(results[7], asyncio.CancelledError)
            for i, r in enumerate(results):
                if i != 7:
                    assert r["taskname"] == f"t{i}"
            assert (await c.state())["cmd"] == 2

    asyncio.run(run())


def test_threads_sharing_one_sync_client_each_get_their_own_response(lluavd):
    daemon = lluavd()
    failures: list[str] = []
    with lluav.Client(daemon.url) as c:

        def worker(t: int) -> None:
            for i in range(25):
                name = f"thread{t}-{i}"
                got = c.set_taskname(name)["taskname"]
                if got != name:
                    failures.append(f"{name} got {got}")

        threads = [threading.Thread(target=worker, args=(t,)) for t in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert failures == []
