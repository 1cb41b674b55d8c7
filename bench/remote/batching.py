"""Dynamic batching for `bench serve batch=N`: many connections' requests answered in one forward pass.

Each connection's thread hands its request to `Batcher.submit` and waits. The batcher's thread takes
the first waiting request, waits at most `wait_s` for more (or until `size` are waiting), groups them
by the policies' `batch_key` (policies with equal keys answer identically: the same weights, spec,
bounds and chunking) and answers each group with one `act_batch(observations)` call. A policy
without `act_batch`/`batch_key` is answered alone, in its own connection's thread, as without batching.

The bounded wait is the knob: a batch goes as soon as `size` requests wait, or as many as there are
connections (`clients()`: every connected worker has asked, nobody else can join), else when the first
request has waited `wait_s`; so a lone worker pays no wait, and workers that are mid-step can join.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Hashable

import numpy as np

from bench.protocols import BatchPolicy, Obs


class _Request:
    __slots__ = ("policy", "obs", "key", "done", "result", "error", "infer_ms", "batch")

    def __init__(self, policy: BatchPolicy, obs: Obs, key: Hashable):
        self.policy, self.obs, self.key = policy, obs, key
        self.done = threading.Event()
        self.result: np.ndarray | None = None
        self.error: BaseException | None = None
        self.infer_ms = 0.0
        self.batch = 1


class Batcher:
    """Collects requests from many threads and answers them in batches of at most `size`."""

    def __init__(self, size: int, wait_s: float, clients: Callable[[], int] | None = None):
        self.size, self.wait_s = max(1, int(size)), max(0.0, float(wait_s))
        self.clients = clients or (lambda: self.size)
        self._cond = threading.Condition()
        self._waiting: list[_Request] = []
        self._closed = False
        self.batches = 0  # forward passes made
        self.answered = 0  # requests answered through them
        self._thread = threading.Thread(target=self._run, name="bench-serve-batch", daemon=True)
        self._thread.start()

    def submit(self, policy: BatchPolicy, obs: Obs) -> tuple[np.ndarray, float, int]:
        """(the policy's answer to `obs`, the batch's forward-pass ms, the batch's size); blocks until done."""
        req = _Request(policy, obs, policy.batch_key)
        with self._cond:
            if self._closed:
                raise RuntimeError("the server is stopping")
            self._waiting.append(req)
            self._cond.notify_all()
        req.done.wait()
        if req.error is not None:
            raise req.error
        assert req.result is not None
        return req.result, req.infer_ms, req.batch

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._waiting and not self._closed:
                    self._cond.wait()
                if self._closed and not self._waiting:
                    return
                deadline = time.monotonic() + self.wait_s
                while len(self._waiting) < min(self.size, max(1, self.clients())) and not self._closed:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    self._cond.wait(left)
                taken, self._waiting = self._waiting[: self.size], self._waiting[self.size :]
            groups: dict[Hashable, list[_Request]] = {}
            for req in taken:
                groups.setdefault(req.key, []).append(req)
            for group in groups.values():
                self._answer(group)

    def _answer(self, group: list[_Request]) -> None:
        t0 = time.perf_counter()
        try:
            outs = group[0].policy.act_batch([r.obs for r in group])
            if len(outs) != len(group):
                raise RuntimeError(f"act_batch answered {len(outs)} actions for {len(group)} observations")
        except BaseException as exc:  # every request of the batch fails with it; the server goes on
            for r in group:
                r.error = exc
                r.done.set()
            return
        ms = (time.perf_counter() - t0) * 1000.0
        self.batches += 1
        self.answered += len(group)
        for r, out in zip(group, outs):
            r.result, r.infer_ms, r.batch = np.asarray(out), ms, len(group)
            r.done.set()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
